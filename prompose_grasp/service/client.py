"""A small client of the perception service, on the standard library (`urllib`): no extra to install.

>>> client = PerceptionClient("http://127.0.0.1:8765")  # doctest: +SKIP
>>> doc = client.estimate_files("rgb.png", "depth.png", (fx, fy, cx, cy), "mustard bottle")  # doctest: +SKIP
>>> doc["objects"][0]["t"]  # doctest: +SKIP

A refused request raises what the library raises for the same input: `InvalidInputError` for a 400 (the
message is the one the CLI prints), `ServiceError` for everything else (no server, 401, 413, 503, ...).
"""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError, PromposeError
from prompose_grasp.service.protocol import encode_array, encode_file

__all__ = ["PerceptionClient", "ServiceError"]


class ServiceError(PromposeError):
    """The service could not be reached or refused the request for a reason other than bad input.

    Attributes:
        status: the HTTP status, or None when no answer came (connection refused, timeout).
    """

    def __init__(self, message: str, status: int | None = None):
        super().__init__(message)
        self.status = status


class PerceptionClient:
    """Requests to a `prompose-grasp serve` service.

    Args:
        url: the service's base URL ("http://127.0.0.1:8765").
        token: the bearer token, when the service was started with one.
        timeout_s: how long to wait for an answer [s] (a request waits its turn in the service's queue).
    """

    def __init__(self, url: str, token: str | None = None, timeout_s: float = 60.0):
        if not isinstance(url, str) or not url.startswith(("http://", "https://")):
            raise InvalidInputError(f"server URL must start with http:// or https://, got {url!r}")
        self.url = url.rstrip("/")
        self.token = token
        self.timeout_s = float(timeout_s)

    def _call(self, method: str, path: str, body: dict[str, Any] | None = None) -> dict[str, Any]:
        data = None if body is None else json.dumps(body).encode()
        headers = {"Accept": "application/json"}
        if data is not None:
            headers["Content-Type"] = "application/json"
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        req = urllib.request.Request(self.url + path, data=data, headers=headers, method=method)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
                return json.loads(resp.read())
        except urllib.error.HTTPError as exc:
            try:
                message = json.loads(exc.read()).get("error") or exc.reason
            except (ValueError, AttributeError):
                message = exc.reason
            if exc.code == 400:
                raise InvalidInputError(str(message)) from None
            raise ServiceError(f"{self.url}{path}: HTTP {exc.code}: {message}", exc.code) from None
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            raise ServiceError(f"no answer from {self.url}: {reason}") from None

    def health(self) -> dict[str, Any]:
        """`GET /v1/health`: status, version, answered / waiting requests, open tracks, memory [MiB]."""
        return self._call("GET", "/v1/health")

    def estimate(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        intrinsics: Sequence[float],
        prompt: str,
        depth_scale: float = 0.001,
        max_objects: int = 3,
    ) -> dict[str, Any]:
        """The estimate document of one frame given as arrays.

        Args:
            rgb: (H, W, 3) uint8, RGB order.
            depth: (H, W) uint16 (scaled by `depth_scale` [m per unit]) or float32 metres.
            intrinsics: (fx, fy, cx, cy) [px].
        """
        body = self._frame(encode_array(rgb, "rgb"), encode_array(depth, "depth"), intrinsics, depth_scale)
        return self._call("POST", "/v1/estimate", {**body, "prompt": prompt, "max_objects": int(max_objects)})

    def estimate_files(
        self,
        rgb_path: str | Path,
        depth_path: str | Path,
        intrinsics: Sequence[float],
        prompt: str,
        depth_scale: float = 0.001,
        max_objects: int = 3,
    ) -> dict[str, Any]:
        """The estimate document of one frame given as image files (sent as they are: PNG stays PNG)."""
        rgb, depth = (self._file(p) for p in (rgb_path, depth_path))
        body = self._frame(rgb, depth, intrinsics, depth_scale)
        return self._call("POST", "/v1/estimate", {**body, "prompt": prompt, "max_objects": int(max_objects)})

    def track(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        intrinsics: Sequence[float],
        prompt: str | None = None,
        track_id: str | None = None,
        depth_scale: float = 0.001,
    ) -> dict[str, Any]:
        """One frame of a track: `{track_id, frame, objects}`. Start with `prompt` (no `track_id`), then pass
        the returned `track_id` with each next frame."""
        body = self._frame(encode_array(rgb, "rgb"), encode_array(depth, "depth"), intrinsics, depth_scale)
        return self._call("POST", "/v1/track", {**body, "prompt": prompt, "track_id": track_id})

    def end_track(self, track_id: str) -> dict[str, Any]:
        """End a track (`DELETE /v1/track/{track_id}`)."""
        return self._call("DELETE", f"/v1/track/{track_id}")

    @staticmethod
    def _file(path: str | Path) -> dict[str, str]:
        p = Path(path)
        if not p.is_file():
            raise InvalidInputError(f"{p}: no such file")
        return encode_file(p.read_bytes(), str(p))

    @staticmethod
    def _frame(rgb: dict, depth: dict, intrinsics: Sequence[float], depth_scale: float) -> dict[str, Any]:
        return {"rgb": rgb, "depth": depth, "intrinsics": [float(v) for v in intrinsics],
                "depth_scale": float(depth_scale)}  # fmt: skip
