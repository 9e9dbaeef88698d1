"""The perception service: FastAPI + uvicorn around one loaded `ProMPose` (extra `serve`).

A cold `prompose-grasp estimate` pays for importing and warming the estimator at every call (docs/
benchmarks.md, "Start-up"); a robot stack that asks for poses all day (a ROS node, a cell controller in
another process) should pay once. The service loads the estimator when it starts and answers:

- `GET /v1/health`: status, version, requests answered, requests waiting, open tracks, resident memory;
- `POST /v1/estimate`: one frame + prompt -> the `prompose-grasp estimate` JSON document;
- `POST /v1/track`: one frame of a sequence; without `track_id` it starts a track (the prompt is needed)
  and returns its id, with it the frame continues that track; `DELETE /v1/track/{track_id}` ends it.

Requests are served one at a time by the estimator (its caches are not shared across threads): others wait
in a queue of `ServiceConfig.max_queue`, beyond which the answer is 503 (retry later), never a crash. Bad
input is a 400 whose `error` is the one-line message the CLI prints for the same input; a body larger than
`max_body_bytes` is a 413, refused from its Content-Length before it is read. With a token, every route
but health and the schema wants `Authorization: Bearer <token>`.
"""

# No `from __future__ import annotations`: FastAPI reads the request models of the routes from their
# annotations at run time, and the models are local to `create_app` (pydantic loads with the extra only).

import logging
import math
import secrets
import threading
import time
import uuid
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from prompose_grasp._optional import require
from prompose_grasp.errors import InvalidInputError, PromposeError
from prompose_grasp.service.protocol import decode_frame, result_document

__all__ = ["ServiceConfig", "create_app", "serve"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ServiceConfig:
    """Settings of the service.

    Attributes:
        host: address to bind; 127.0.0.1 (this machine only) unless you mean to expose it.
        port: TCP port; 0 picks a free one (printed when the server is up).
        token: when set, requests other than health need `Authorization: Bearer <token>`.
        max_body_bytes: larger request bodies are refused (413) before they are read: 32 MiB holds a
            1920 x 1080 frame as raw RGB + float32 depth in base64 (~19 MB).
        max_queue: requests that may wait for the estimator; more get 503.
        max_tracks: open tracks; starting one more ends the least recently used.
        track_idle_s: a track not fed for this long [s] is ended.
        device: torch device of the estimator.
    """

    host: str = "127.0.0.1"
    port: int = 8765
    token: str | None = None
    max_body_bytes: int = 32 * 2**20
    max_queue: int = 32
    max_tracks: int = 16
    track_idle_s: float = 300.0
    device: str = "cpu"

    def __post_init__(self) -> None:
        if not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise InvalidInputError(f"port must be 0-65535, got {self.port!r}")
        for name in ("max_body_bytes", "max_queue", "max_tracks"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidInputError(f"{name} must be an integer >= 1, got {v!r}")
        if not (isinstance(self.track_idle_s, int | float) and 0 < self.track_idle_s < math.inf):
            raise InvalidInputError(
                f"track_idle_s must be a positive number of seconds, got {self.track_idle_s!r}"
            )
        if self.token is not None and (not isinstance(self.token, str) or not self.token.strip()):
            raise InvalidInputError("token must be a non-blank string (or None for no token)")


def _rss_mb() -> float | None:
    """Resident memory of this process [MiB] (Linux `/proc/self/statm`), or None elsewhere."""
    try:
        import os

        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return None


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


#: Routes answered without the token: liveness, and the API's description (nothing of the estimator's).
_PUBLIC_PATHS = frozenset({"/v1/health", "/openapi.json", "/docs", "/docs/oauth2-redirect", "/redoc"})


class _Busy(Exception):
    pass


class _Runner:
    """The estimator behind one lock, with a bounded number of waiting requests, and the open tracks."""

    def __init__(self, estimator: Any, config: ServiceConfig):
        self.estimator = estimator
        self.config = config
        self._lock = threading.Lock()
        self._count_lock = threading.Lock()
        self.waiting = 0
        self.answered = 0
        self.tracks: OrderedDict[str, tuple[Any, int, float]] = (
            OrderedDict()
        )  # id -> (tracker, frames, last s)

    def run(self, fn: Any) -> Any:
        with self._count_lock:
            if self.waiting >= self.config.max_queue:
                raise _Busy
            self.waiting += 1
        try:
            with self._lock:
                self._expire_tracks()
                out = fn()
                self.answered += 1
                return out
        finally:
            with self._count_lock:
                self.waiting -= 1

    def _expire_tracks(self) -> None:
        now = time.monotonic()
        for tid in [t for t, (_, _, last) in self.tracks.items() if now - last > self.config.track_idle_s]:
            del self.tracks[tid]
            log.info("track %s ended: idle for more than %g s", tid, self.config.track_idle_s)


def create_app(config: ServiceConfig | None = None, estimator: Any | None = None) -> Any:
    """The FastAPI application (module docstring), with `estimator` (default: `ProMPose.default(device)`,
    loaded now) behind it.

    Raises:
        MissingDependencyError: fastapi is not installed (extra `serve`).
    """
    fastapi = require("fastapi", extra="serve")
    from fastapi.exceptions import RequestValidationError
    from fastapi.responses import JSONResponse
    from pydantic import BaseModel, Field

    import prompose_grasp

    config = config or ServiceConfig()
    if estimator is None:
        from prompose_grasp.perception.estimator import ProMPose

        t0 = time.perf_counter()
        estimator = ProMPose.default(config.device)
        log.info("estimator loaded in %.2f s", time.perf_counter() - t0)
    runner = _Runner(estimator, config)
    started = time.monotonic()

    class Image(BaseModel):
        """An image: a PNG / JPEG file (`png`) or a raw array (`raw` + `shape` + `dtype`), base64."""

        png: str | None = Field(None, description="base64 of a PNG / JPEG file (a 16-bit PNG for depth)")
        raw: str | None = Field(None, description="base64 of the array's bytes, C order, little-endian")
        shape: list[int] | None = Field(None, description="[H, W, 3] colour, [H, W] depth (with raw)")
        dtype: str | None = Field(None, description="uint8 colour; uint16 (scaled) or float32 metres depth")
        name: str | None = Field(None, description="what error messages call this image (e.g. its path)")

    class FrameRequest(BaseModel):
        intrinsics: list[float] = Field(
            ..., description="[fx, fy, cx, cy] in pixels", min_length=4, max_length=4
        )
        depth_scale: float = Field(0.001, description="metres per unit of a uint16 depth")
        rgb: Image
        depth: Image

    class EstimateRequest(FrameRequest):
        prompt: str = Field(..., description='the object, e.g. "mustard bottle"')
        max_objects: int = Field(3, description="candidates to report, best first", ge=1)

    class TrackRequest(FrameRequest):
        track_id: str | None = Field(None, description="the track to continue; omit to start one")
        prompt: str | None = Field(None, description="the object; needed to start a track")

    app = fastapi.FastAPI(
        title="prompose_grasp perception service",
        version=prompose_grasp.__version__,
        description="ProM-Pose 9-DoF estimates of the object a prompt names, from RGB-D frames "
        "(docs/service.md).",
    )

    def error(status: int, message: str, headers: dict[str, str] | None = None) -> Any:
        return JSONResponse({"error": message}, status_code=status, headers=headers)

    @app.middleware("http")
    async def limits_and_token(request: Any, call_next: Any) -> Any:
        if request.method in ("POST", "PUT", "PATCH"):
            length = request.headers.get("content-length")
            if length is None:
                return error(411, "a request body needs a Content-Length header")
            if not length.isdigit() or int(length) > config.max_body_bytes:
                return error(
                    413,
                    f"request body of {length} bytes is larger than the limit of "
                    f"{config.max_body_bytes} bytes",
                )
        if config.token is not None and request.url.path not in _PUBLIC_PATHS:
            given = request.headers.get("authorization", "")
            if not secrets.compare_digest(given.encode(), f"Bearer {config.token}".encode()):
                # read the (size-checked) body first: a client still sending would see a broken pipe, not 401
                await request.body()
                return error(401, "missing or wrong bearer token", {"WWW-Authenticate": "Bearer"})
        return await call_next(request)

    @app.exception_handler(RequestValidationError)
    async def bad_request_shape(request: Any, exc: Any) -> Any:
        first = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p != "body") or "body"
        return error(422, f"{where}: {first.get('msg', 'invalid request')}")

    @app.exception_handler(PromposeError)
    async def prompose_error(request: Any, exc: PromposeError) -> Any:
        return error(400 if isinstance(exc, InvalidInputError) else 422, _one_line(exc))

    @app.exception_handler(_Busy)
    async def busy(request: Any, exc: Any) -> Any:
        return error(
            503, f"{config.max_queue} requests are already waiting; retry later", {"Retry-After": "1"}
        )

    @app.get("/v1/health")
    def health() -> dict[str, Any]:
        """Liveness and load: answered and waiting requests, open tracks, resident memory [MiB]."""
        return {
            "status": "ok",
            "version": prompose_grasp.__version__,
            "answered": runner.answered,
            "waiting": runner.waiting,
            "tracks": len(runner.tracks),
            "uptime_s": round(time.monotonic() - started, 3),
            "rss_mb": _rss_mb(),
        }

    @app.post("/v1/estimate")
    def estimate(req: EstimateRequest) -> dict[str, Any]:
        """The `prompose-grasp estimate` JSON document of one frame: objects best first, [] when none fits."""
        from prompose_grasp.perception.grounding.language import check_prompt

        body = req.model_dump()
        check_prompt(req.prompt, "prompt")
        frame = decode_frame(body)
        return runner.run(
            lambda: result_document(
                req.prompt, estimator.estimate_all(frame, req.prompt, max_objects=req.max_objects)
            )
        )

    @app.post("/v1/track")
    def track(req: TrackRequest) -> dict[str, Any]:
        """One frame of a track: `{track_id, frame, objects: [the tracked object]}` (the estimate contract's
        object fields; frame counts from 0 per track)."""
        from prompose_grasp.perception.grounding.language import check_prompt
        from prompose_grasp.perception.tracker import Tracker

        frame = decode_frame(req.model_dump())
        if req.track_id is None:
            if req.prompt is None:
                raise InvalidInputError("prompt is needed to start a track (no track_id given)")
            prompt = check_prompt(req.prompt, "prompt")
        elif req.track_id not in runner.tracks:
            raise InvalidInputError(
                f"track_id {req.track_id!r} is not an open track (ended, expired or never started)"
            )

        def step() -> dict[str, Any]:
            if req.track_id is None:
                tid = uuid.uuid4().hex
                tracker, k = Tracker(estimator, prompt), 0
                while len(runner.tracks) >= config.max_tracks:
                    old, _ = runner.tracks.popitem(last=False)
                    log.info("track %s ended: %d tracks open", old, config.max_tracks)
            else:
                tid = req.track_id
                if tid not in runner.tracks:  # expired while this request waited
                    raise InvalidInputError(
                        f"track_id {tid!r} is not an open track (ended, expired or never started)"
                    )
                tracker, k, _ = runner.tracks[tid]  # kept if this frame fails: the next one may go on
                runner.tracks.move_to_end(tid)
            est = tracker.update(frame)
            runner.tracks[tid] = (tracker, k + 1, time.monotonic())
            return {"track_id": tid, "frame": k, "objects": [est.to_dict()]}

        return runner.run(step)

    @app.delete("/v1/track/{track_id}")
    def end_track(track_id: str) -> dict[str, Any]:
        """End a track; its id is not valid afterwards."""

        def end() -> dict[str, Any]:
            if runner.tracks.pop(track_id, None) is None:
                raise InvalidInputError(
                    f"track_id {track_id!r} is not an open track (ended, expired or never started)"
                )
            return {"track_id": track_id, "ended": True}

        return runner.run(end)  # in turn: a track is never ended while a frame of it is being fitted

    return app


def serve(config: ServiceConfig | None = None, estimator: Any | None = None, ready: Any = None) -> None:
    """Load the estimator, bind `config.host:config.port` and serve until interrupted (SIGINT / SIGTERM).

    Args:
        ready: called with the URL ("http://127.0.0.1:8765") once the socket is bound, before serving; the
            CLI prints it (with port 0 it names the port picked).
    """
    import socket

    uvicorn = require("uvicorn", extra="serve")
    config = config or ServiceConfig()
    app = create_app(config, estimator)
    family = socket.AF_INET6 if ":" in config.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((config.host, config.port))
    except OSError as exc:
        sock.close()
        raise InvalidInputError(
            f"cannot listen on {config.host}:{config.port}: {exc.strerror or exc}"
        ) from None
    host, port = sock.getsockname()[:2]
    url = f"http://[{host}]:{port}" if family == socket.AF_INET6 else f"http://{host}:{port}"
    if ready is not None:
        ready(url)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False))
    server.run(sockets=[sock])
