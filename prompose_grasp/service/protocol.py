"""The service's wire format, shared by the server and the client: frames as JSON and the result document.

A frame travels as JSON: `{"prompt", "intrinsics": [fx, fy, cx, cy], "depth_scale", "rgb": IMAGE,
"depth": IMAGE}`, where IMAGE is either a PNG / JPEG file `{"png": base64, "name": str}` or a raw array
`{"raw": base64, "shape": [H, W(, 3)], "dtype": "uint8" | "uint16" | "float32", "name": str}` (C order,
little-endian; a float32 depth is metres and ignores `depth_scale`). `name` is what error messages call the
image: the client sends the file's path, so a bad file gets the message the CLI prints for it.

The result document is the `prompose-grasp estimate` JSON contract (DESIGN.md).
"""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError

__all__ = ["RAW_DTYPES", "decode_frame", "encode_array", "encode_file", "result_document"]

#: dtypes a raw image may have: colour uint8; depth uint16 (scaled by depth_scale) or float32 metres
RAW_DTYPES = ("uint8", "uint16", "float32")


def encode_file(data: bytes, name: str) -> dict[str, str]:
    """An image file's bytes as the IMAGE object (`{"png": base64, "name": name}`)."""
    return {"png": base64.b64encode(data).decode("ascii"), "name": name}


def encode_array(array: np.ndarray, name: str) -> dict[str, Any]:
    """An (H, W) / (H, W, 3) array as the IMAGE object (raw little-endian bytes, base64)."""
    a = np.asarray(array)
    if a.dtype.name not in RAW_DTYPES:
        raise InvalidInputError(f"{name}: a raw image is one of {', '.join(RAW_DTYPES)}, got {a.dtype}")
    data = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes()
    return {"raw": base64.b64encode(data).decode("ascii"), "shape": list(a.shape), "dtype": a.dtype.name,
            "name": name}  # fmt: skip


def _b64(text: object, name: str) -> bytes:
    if not isinstance(text, str):
        raise InvalidInputError(f"{name}: the image data must be a base64 string")
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise InvalidInputError(f"{name}: the image data is not valid base64") from None


def _image(obj: object, field: str, depth: bool) -> tuple[np.ndarray, str]:
    from prompose_grasp.perception.frames_io import decode_image

    if not isinstance(obj, Mapping):
        raise InvalidInputError(f"{field} must be an object with 'png' (base64 file) or 'raw' (base64 array)")
    name = str(obj.get("name") or field)
    if (obj.get("png") is None) == (obj.get("raw") is None):
        raise InvalidInputError(f"{name}: give exactly one of 'png' (an image file) or 'raw' (an array)")
    if obj.get("png") is not None:
        return decode_image(_b64(obj["png"], name), name, depth=depth), name
    dtype, shape = obj.get("dtype"), obj.get("shape")
    if dtype not in RAW_DTYPES:
        raise InvalidInputError(f"{name}: dtype must be one of {', '.join(RAW_DTYPES)}, got {dtype!r}")
    if not isinstance(shape, Sequence) or not all(isinstance(n, int) and n > 0 for n in shape):
        raise InvalidInputError(f"{name}: shape must be a list of positive integers, got {shape!r}")
    data = _b64(obj["raw"], name)
    want = math.prod(shape) * np.dtype(dtype).itemsize
    if len(data) != want:
        raise InvalidInputError(
            f"{name}: {len(data)} bytes do not make a {dtype} array of shape {list(shape)}"
        )
    return np.frombuffer(data, dtype=np.dtype(dtype).newbyteorder("<")).astype(dtype).reshape(shape), name


def decode_frame(body: Mapping[str, Any], timestamp_s: float = 0.0) -> Any:
    """The `RGBDFrame` of a request body (module docstring), checked as the CLI checks files.

    Raises:
        InvalidInputError: a missing or malformed field, an undecodable image, or a frame `load_rgbd` would
            refuse (the same message).
    """
    from prompose_grasp.perception.frames_io import frame_from_images

    intrinsics = body.get("intrinsics")
    if (
        not isinstance(intrinsics, Sequence)
        or len(intrinsics) != 4
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in intrinsics)
    ):
        raise InvalidInputError(
            f"intrinsics must be 4 numbers [fx, fy, cx, cy] in pixels, got {intrinsics!r}"
        )
    scale = body.get("depth_scale", 0.001)
    if isinstance(scale, bool) or not isinstance(scale, int | float):
        raise InvalidInputError(f"depth_scale must be a number of metres per unit, got {scale!r}")
    rgb, rgb_name = _image(body.get("rgb"), "rgb", depth=False)
    depth, depth_name = _image(body.get("depth"), "depth", depth=True)
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    return frame_from_images(
        rgb, depth, float(scale), (fx, fy, cx, cy), timestamp_s, rgb_name=rgb_name, depth_name=depth_name
    )


def result_document(prompt: str, estimates: Sequence[Any]) -> dict[str, Any]:
    """The `prompose-grasp estimate` JSON document of `ProMPose.estimate_all`'s answer (DESIGN.md)."""
    timing = dict(estimates[0].timings_ms) if estimates else {}
    return {
        "prompt": prompt,
        # 1: the first object is the one named; >= 2: that many fit the words about equally; 0: none does
        "contenders": int(estimates[0].contenders) if estimates else 0,
        "objects": [e.to_dict() for e in estimates],
        "timing_ms": {
            k: round(float(timing.get(k, 0.0)), 3) for k in ("grounding", "prior", "pose", "total")
        },
    }
