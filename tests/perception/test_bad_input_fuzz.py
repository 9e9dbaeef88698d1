"""Seeded malformed input to `RGBDFrame` and to `ProMPose.estimate / estimate_all / track`: every case ends in
a `PromposeError` whose message is one line, raised before any grounding or fitting runs.

Each case is built to be malformed by construction (a wrong type, shape or dtype, a unit mistake of the whole
image, impossible intrinsics, a prompt without a Latin letter, ...); values that are merely unusual but valid
(a few negative or NaN depth pixels, a principal point outside a cropped image) are left out on purpose.
Images are 64 x 48 so that the cases cost microseconds; the estimator is built once for the module.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from prompose_grasp import ProMPose
from prompose_grasp.errors import PromposeError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.robot import RGBDFrame

W, H = 64, 48
K = CameraIntrinsics(60.0, 60.0, 31.5, 23.5, W, H)
N_FRAME_CASES = 500
N_ESTIMATOR_CASES = 300

# Scripts without a Latin letter: the estimator refuses them (the text encoder reads English).
_NON_LATIN_RANGES = (
    (0x3041, 0x3096),  # hiragana
    (0x30A1, 0x30FA),  # katakana
    (0x4E00, 0x9FFF),  # CJK ideographs
    (0x0621, 0x064A),  # Arabic letters
    (0x0410, 0x044F),  # Cyrillic
    (0x1F300, 0x1F5FF),  # pictographs (emoji)
)


def _good_parts(rng: np.random.Generator) -> dict:
    """The arguments of a valid frame: a table 0.5-1.5 m away, random colours."""
    return {
        "rgb": rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
        "depth_m": rng.uniform(0.5, 1.5, (H, W)).astype(np.float32),
        "intrinsics": K,
        "timestamp_s": float(rng.uniform(0, 100)),
    }


def _non_latin_text(rng: np.random.Generator) -> str:
    lo, hi = _NON_LATIN_RANGES[rng.integers(len(_NON_LATIN_RANGES))]
    n = int(rng.integers(1, 8))
    text = "".join(chr(int(c)) for c in rng.integers(lo, hi + 1, n))
    return text + rng.choice(["", " ", "　", "!", "123"])  # full-width space, punctuation, digits


def _bad_frame_kwargs(rng: np.random.Generator) -> tuple[str, dict]:
    """(label, RGBDFrame kwargs) with exactly one malformed argument."""
    kw = _good_parts(rng)
    kind = int(rng.integers(14))
    if kind == 0:  # rgb of the wrong shape
        shape = [(H, W), (H, W, 4), (H + 1, W, 3), (W, H, 3), (H, W, 3, 1), (3, H, W), ()][rng.integers(7)]
        kw["rgb"] = np.zeros(shape, np.uint8)
    elif kind == 1:  # rgb of the wrong dtype
        dtype = [np.float32, np.float64, np.uint16, np.int64, np.bool_, np.int8][rng.integers(6)]
        kw["rgb"] = kw["rgb"].astype(dtype)
    elif kind == 2:  # rgb that is no array
        kw["rgb"] = [None, "image.png", [[1, 2], [3]], {"r": 1}, 3.5][rng.integers(5)]
    elif kind == 3:  # depth of the wrong shape (incl. colour and depth sizes that disagree)
        shape = [(H, W - 1), (H - 1, W), (W, H), (H, W, 1), (H * W,), (H, W, 3)][rng.integers(6)]
        kw["depth_m"] = rng.uniform(0.5, 1.5, shape).astype(np.float32)
    elif kind == 4:  # depth of the wrong dtype (uint16 millimetres, float64, ints)
        dtype = [np.float64, np.uint16, np.int32, np.float16, np.bool_][rng.integers(5)]
        kw["depth_m"] = (kw["depth_m"] * (1000 if dtype == np.uint16 else 1)).astype(dtype)
    elif kind == 5:  # depth that is no array
        kw["depth_m"] = [None, "depth.png", [[0.5], [0.5, 0.6]], 0.8][rng.integers(4)]
    elif kind == 6:  # millimetres passed as metres (a table at 0.5-1.5 m reads 500-1500)
        kw["depth_m"] = (kw["depth_m"] * 1000.0).astype(np.float32)
    elif kind == 7:  # a whole image beyond any sensor, or nearer than any
        scale = 10.0 ** rng.uniform(2.5, 30) if rng.random() < 0.5 else 10.0 ** rng.uniform(-2.7, -1.6)
        kw["depth_m"] = (kw["depth_m"] * scale).astype(np.float32)
        kw["depth_m"][~np.isfinite(kw["depth_m"])] = np.float32(3e38)  # float32 overflow: still huge
    elif kind == 8:  # the sign of the whole image flipped, some holes left
        d = -kw["depth_m"]
        d[rng.random(d.shape) < rng.uniform(0, 0.4)] = 0.0
        kw["depth_m"] = d
    elif kind == 9:  # intrinsics that are no CameraIntrinsics (a K matrix, a tuple, None, ...)
        kw["intrinsics"] = [None, (60.0, 60.0, 31.5, 23.5), K.K, {"fx": 60.0}, "K", [60, 60, 31.5, 23.5]][
            rng.integers(6)
        ]
    elif kind == 10:  # intrinsics of another image size
        w, h = [(W + 1, H), (W, H - 1), (H, W), (2 * W, 2 * H)][rng.integers(4)]
        kw["intrinsics"] = CameraIntrinsics(60.0, 60.0, (w - 1) / 2, (h - 1) / 2, w, h)
    elif kind == 11:  # intrinsics no camera has: a tiny focal length, or the axis far off the image
        if rng.random() < 0.5:
            f = float(10.0 ** rng.uniform(-3, math.log10(5.0)))  # < 5 px on a 64 px image: > 160 deg
            kw["intrinsics"] = CameraIntrinsics(f, f, 31.5, 23.5, W, H)
        else:
            cx = float(rng.choice([-1, 1]) * rng.uniform(10, 1000) * W)  # > 10 image widths off centre
            kw["intrinsics"] = CameraIntrinsics(60.0, 60.0, cx, 23.5, W, H)
    elif kind == 12:  # a timestamp that is no finite number
        bad = [None, "0", "now", math.nan, math.inf, -math.inf, True, [0.0], 1j]
        kw["timestamp_s"] = bad[rng.integers(len(bad))]
    else:  # T_base_cam that is no rigid transform
        bad = [np.eye(3), np.full((4, 4), np.nan), rng.normal(size=(4, 4)), "identity", np.eye(4)[:3]]
        T = bad[rng.integers(len(bad))]
        if rng.random() < 0.3:
            T = np.eye(4)
            T[3] = [0.0, 0.0, 1.0, 1.0]  # last row not (0, 0, 0, 1)
        kw["T_base_cam"] = T
    return f"frame kind {kind}", kw


def _bad_intrinsics(rng: np.random.Generator) -> tuple[str, object]:
    """(label, a call) of CameraIntrinsics with a negative, zero, NaN, inf or non-numeric field."""
    values = [60.0, 60.0, 31.5, 23.5, W, H]
    i = int(rng.integers(6))
    if i < 2:
        values[i] = [-60.0, 0.0, math.nan, math.inf, "60", None, True][rng.integers(7)]
    elif i < 4:
        values[i] = [math.nan, math.inf, -math.inf, "31.5", None, [31.5]][rng.integers(6)]
    else:
        values[i] = [0, -W, 64.5, "64", None, True, math.nan][rng.integers(7)]
    return f"intrinsics field {i}", lambda: CameraIntrinsics(*values)


def _run_case(label: str, call, failures: list[str]) -> None:
    try:
        call()
    except PromposeError as exc:
        message = str(exc)
        if not message.strip() or "\n" in message:
            failures.append(f"{label}: message is not one line: {message!r}")
    except Exception as exc:  # the point of the test: no foreign exception escapes
        failures.append(f"{label}: {type(exc).__name__}: {exc}")
    else:
        failures.append(f"{label}: accepted")


def test_malformed_frames_are_refused():
    rng = np.random.default_rng(20270)
    failures: list[str] = []
    t0 = time.perf_counter()
    for k in range(N_FRAME_CASES):
        if k % 5 == 4:
            label, call = _bad_intrinsics(rng)
        else:
            label, kw = _bad_frame_kwargs(rng)
            call = lambda kw=kw: RGBDFrame(**kw)  # noqa: E731
        _run_case(f"case {k} ({label})", call, failures)
    assert not failures, "\n".join(failures[:20])
    assert time.perf_counter() - t0 < 30.0  # microseconds a case: validation, no work


@pytest.fixture(scope="module")
def estimator():
    return ProMPose.default()


def _bad_estimator_call(estimator: ProMPose, rng: np.random.Generator) -> tuple[str, object]:
    """(label, a call) of estimate / estimate_all / track with one malformed argument."""
    frame = RGBDFrame(**_good_parts(rng))
    kind = int(rng.integers(10))
    if kind == 0:  # not a frame
        bad = [None, (frame.rgb, frame.depth_m), {"rgb": frame.rgb}, "frame.png", frame.rgb, [frame]]
        other = bad[rng.integers(len(bad))]
        return "not a frame", lambda: estimator.estimate(other, "the mug")
    if kind == 1:  # a frame without a single depth reading (all zero, NaN, inf, below 1 mm)
        fill = [0.0, math.nan, math.inf, 5e-4][rng.integers(4)]
        empty = RGBDFrame(frame.rgb, np.full((H, W), fill, np.float32), K, 0.0)
        return "no depth reading", lambda: estimator.estimate(empty, "the mug")
    if kind == 2:  # a prompt that is no str, or blank
        prompt = [None, 5, b"mug", "", "   ", "\t\n", ["mug"], 3.5][rng.integers(8)]
        return f"prompt {prompt!r}", lambda: estimator.estimate(frame, prompt)
    if kind == 3:  # a prompt without a Latin letter (Japanese, Chinese, Arabic, Cyrillic, emoji)
        prompt = _non_latin_text(rng)
        method = [estimator.estimate, estimator.estimate_all][rng.integers(2)]
        return f"prompt {prompt!r}", lambda: method(frame, prompt)
    if kind == 4:  # max_objects that is no integer >= 1
        n = ["3", 0, -5, True, False, 2.5, math.nan, [3]][rng.integers(8)]
        return f"max_objects {n!r}", lambda: estimator.estimate_all(frame, "the mug", max_objects=n)
    if kind == 5:  # min_score_ratio outside [0, 1] or no number
        r = [-0.1, 1.5, math.nan, math.inf, "0.5", True, None][rng.integers(7)]
        return f"min_score_ratio {r!r}", lambda: estimator.estimate_all(frame, "the mug", min_score_ratio=r)
    if kind == 6:  # a prior that is no ShapePrior
        prior = ["box", 5, {"name": "box"}, np.zeros((10, 3))][rng.integers(4)]
        return f"prior {type(prior).__name__}", lambda: estimator.estimate(frame, "the box", prior=prior)
    if kind == 7:  # a mask of the wrong shape or dtype, or one holding no depth point
        bad = [
            np.ones((H, W - 1), bool),
            np.ones((H, W), np.uint8),
            np.ones((H, W), np.float32),
            np.zeros((H, W), bool),
            "mask",
            [[True, False], [True]],
        ]
        m = bad[rng.integers(len(bad))]
        return "bad mask", lambda: estimator.estimate(frame, "the box", mask=m)
    if kind == 8:  # track given one frame, or something that is no sequence of frames
        frames = [frame, 5, None, "frames", frame.rgb][rng.integers(5)]
        return f"track {type(frames).__name__}", lambda: estimator.track(frames, "the box")
    # track of a sequence holding something else than frames (refused when it comes), or a bad prompt
    if rng.random() < 0.5:
        items = [[None], [frame.rgb], [(frame.rgb, frame.depth_m)], ["000000-color.png"]][rng.integers(4)]
        return "track item", lambda: list(estimator.track(items, "the box"))
    prompt = [_non_latin_text(rng), "", None][rng.integers(3)]
    return f"track prompt {prompt!r}", lambda: estimator.track([frame], prompt)


def test_malformed_estimator_calls_are_refused_before_any_work(estimator, monkeypatch):
    def no_grounding(*args, **kwargs):
        raise AssertionError("grounding ran on malformed input")

    monkeypatch.setattr(estimator.grounder, "ground", no_grounding)
    rng = np.random.default_rng(20271)
    failures: list[str] = []
    t0 = time.perf_counter()
    for k in range(N_ESTIMATOR_CASES):
        label, call = _bad_estimator_call(estimator, rng)
        _run_case(f"case {k} ({label})", call, failures)
    assert not failures, "\n".join(failures[:20])
    assert time.perf_counter() - t0 < 30.0  # validation only: no grounding, prior or fit
