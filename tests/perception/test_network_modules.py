"""The network's modules one by one (tiny config): shapes, weight sharing, attention roles, invariances, the
rotation helpers and the losses on hand-built cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from network_fixtures import random_inputs

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import random_rotation, rotation_angle, so3_exp
from prompose_grasp.perception.network import CONFIGS, NetworkConfig, ProMPoseNet, network_config, pose_loss
from prompose_grasp.perception.network.fusion import AsymmetricCrossModalAttention
from prompose_grasp.perception.network.geometry import GeometryEncoder, farthest_point_indices
from prompose_grasp.perception.network.heads import RotationTranslationHead, ScaleHead
from prompose_grasp.perception.network.losses import chamfer_squared, symmetric_rotation_error, symmetry_codes
from prompose_grasp.perception.network.model import canonicalize_points
from prompose_grasp.perception.network.pose_tokens import PoseTokenExtractor
from prompose_grasp.perception.network.rotations import geodesic_angle, rotation_6d_to_matrix
from prompose_grasp.perception.network.temporal import TemporalTransformer
from prompose_grasp.perception.network.visual import SmallVisualEncoder

torch.set_num_threads(1)
TINY = network_config("tiny")


@pytest.fixture(scope="module")
def model() -> ProMPoseNet:
    torch.manual_seed(0)
    return ProMPoseNet(TINY).eval()


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


# ------------------------------------------------------------------------------------------------------------
# Config


def test_paper_config_has_the_paper_sizes():
    c = CONFIGS["paper"]
    assert (c.latent_dim, c.num_heads, c.window, c.geometry_dim) == (512, 8, 16, 256)
    assert (c.observed_points, c.prior_points) == (2048, 5000)


def test_config_validation_and_round_trip():
    with pytest.raises(UnknownNameError, match="tiny"):
        network_config("huge")
    with pytest.raises(InvalidInputError, match="divisible"):
        TINY.with_(num_heads=5)
    with pytest.raises(UnknownNameError, match="visual backbone"):
        TINY.with_(visual_backbone="resnet")
    with pytest.raises(InvalidInputError, match="positive int"):
        TINY.with_(window=0)
    assert NetworkConfig.from_dict(TINY.to_dict()) == TINY
    with pytest.raises(UnknownNameError, match="latent_dim"):
        NetworkConfig.from_dict({**TINY.to_dict(), "latent": 3})


# ------------------------------------------------------------------------------------------------------------
# Shapes of every module's forward


def test_module_shapes():
    torch.manual_seed(0)
    B, d, C = 3, TINY.latent_dim, TINY.geometry_dim
    vis = SmallVisualEncoder(TINY)(torch.rand(B, 3, TINY.crop_px, TINY.crop_px))["tokens"]
    assert vis.shape == (B, TINY.visual_tokens, d)

    geo = GeometryEncoder(TINY)(torch.randn(B, TINY.observed_points, 3))
    M = TINY.observed_points // 8  # strides (4, 2)
    assert geo["tokens"].shape == (B, M, C) and geo["positions"].shape == (B, M, 3)
    assert geo["global"].shape == (B, C)

    prior = GeometryEncoder(TINY)(torch.randn(B, TINY.prior_points, 3))["tokens"]
    aca = AsymmetricCrossModalAttention(TINY)(
        vis, geo["tokens"], prior, torch.randn(B, 6, TINY.text_dim), torch.ones(B, 6, dtype=torch.bool)
    )
    assert aca["fused"].shape == (B, TINY.visual_tokens, d)
    assert aca["attention"].shape == (B, TINY.visual_tokens, M + prior.shape[1] + 6)

    z = PoseTokenExtractor(TINY)(aca["fused"], torch.randn(B, 15), geo["global"])
    assert all(z[k].shape == (B, d) for k in ("rotation", "translation", "scale"))

    n = TINY.window
    h = TemporalTransformer(TINY)(torch.randn(B, n, 3, d), torch.ones(B, n, dtype=torch.bool))["features"]
    assert h.shape == (B, n, 3, d)

    rt = RotationTranslationHead(TINY)(h[:, :, 0], h[:, :, 1], prior)
    assert rt["rot6d"].shape == (B, n, 6) and rt["translation_offset"].shape == (B, n, 3)
    assert ScaleHead(TINY)(h[:, :, 2])["log_size_offset"].shape == (B, n, 3)


def test_model_forward_shapes_and_valid_rotations(model):
    B, n = 2, TINY.window
    with torch.no_grad():
        out = model(**random_inputs(TINY, B=B, n=n))
    assert out["R"].shape == (B, n, 3, 3) and out["t"].shape == (B, n, 3) and out["size"].shape == (B, n, 3)
    assert out["tokens"].shape == (B, n, 3, TINY.latent_dim) and out["features"].shape == out["tokens"].shape
    R = out["R"].double()
    eye = torch.eye(3, dtype=torch.float64).expand_as(R)
    # float32 Gram-Schmidt: orthonormal to a few ulps of 1
    assert torch.allclose(R.transpose(-1, -2) @ R, eye, atol=1e-5)
    assert torch.allclose(torch.linalg.det(R), torch.ones(B, n, dtype=torch.float64), atol=1e-5)
    assert bool((out["size"] > 0).all())


def test_shorter_window_and_padded_frames(model):
    x = random_inputs(TINY, B=1, n=2)
    with torch.no_grad():
        out = model(**x)
    assert out["t"].shape == (1, 2, 3)
    # A padded frame is masked as a key: the valid frame's output does not depend on its content.
    x["frame_valid"] = torch.tensor([[True, False]])
    y = {k: v.clone() for k, v in x.items()}
    y["points"][:, 1] += 0.3
    y["crops"][:, 1] = 1.0 - y["crops"][:, 1]
    with torch.no_grad():
        a, b = model(**x), model(**y)
    # identical float32 arithmetic on the valid frame; the masked keys get exactly zero weight
    assert torch.allclose(a["t"][:, 0], b["t"][:, 0], atol=1e-6)
    assert not torch.allclose(a["t"][:, 1], b["t"][:, 1], atol=1e-4)


def test_geometry_encoder_is_shared_by_all_three_streams(model):
    encoders = [m for m in model.modules() if isinstance(m, GeometryEncoder)]
    assert len(encoders) == 1
    calls = []
    handle = encoders[0].register_forward_hook(lambda m, inp, out: calls.append(inp[0].shape))
    try:
        with torch.no_grad():
            model(**random_inputs(TINY, B=2, n=3))
    finally:
        handle.remove()
    # one call for the metric + canonical observation (stacked), one for the prior
    assert calls == [(2 * 2 * 3, TINY.observed_points, 3), (2, TINY.prior_points, 3)]


def test_aca_uses_visual_tokens_as_queries():
    torch.manual_seed(1)
    aca = AsymmetricCrossModalAttention(TINY).eval()
    B, d, C = 2, TINY.latent_dim, TINY.geometry_dim
    obs, prior, text = torch.randn(B, 10, C), torch.randn(B, 12, C), torch.randn(B, 4, TINY.text_dim)
    valid = torch.ones(B, 4, dtype=torch.bool)
    for nv in (5, 17):
        out = aca(torch.randn(B, nv, d), obs, prior, text, valid)
        assert out["fused"].shape == (B, nv, d)  # one output per visual token, whatever the context size
        assert torch.allclose(out["attention"].sum(-1), torch.ones(B, nv), atol=1e-5)  # softmax rows
    # Padded text tokens get no attention.
    valid[:, 2:] = False
    with torch.no_grad():
        w = aca(torch.randn(B, 5, d), obs, prior, text, valid)["attention"]
    assert float(w[..., 10 + 12 + 2 :].abs().max()) == 0.0


def test_geometry_encoder_is_invariant_to_point_order():
    torch.manual_seed(2)
    enc = GeometryEncoder(TINY).eval()
    pts = torch.randn(2, TINY.observed_points, 3)
    perm = torch.randperm(TINY.observed_points)
    with torch.no_grad():
        a, b = enc(pts), enc(pts[:, perm])
    # the same FPS centres in the same order and the same neighbourhoods; only summation order differs
    assert torch.allclose(a["tokens"], b["tokens"], atol=1e-5)
    assert torch.allclose(a["global"], b["global"], atol=1e-5)
    assert torch.equal(a["positions"], b["positions"])


def test_farthest_point_indices_spread_and_start():
    pts = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [0.1, 0, 0], [-2, 0, 0], [0.9, 0, 0]]])
    idx = farthest_point_indices(pts, 3)[0].tolist()
    assert idx[0] == 3  # farthest from the centroid (0, 0, 0)
    assert idx[1] == 1 and idx[2] in (0, 2)


def test_canonicalize_points_unit_box():
    pts = torch.tensor([[0.1, 0.2, 0.7], [0.3, 0.25, 0.9], [0.2, 0.3, 0.8]])
    c = canonicalize_points(pts)
    assert torch.allclose(c.amax(0) - c.amin(0), torch.ones(3))  # exact up to float32 rounding
    assert torch.allclose(c.amax(0) + c.amin(0), torch.zeros(3), atol=1e-6)


# ------------------------------------------------------------------------------------------------------------
# Rotations and losses


def test_rotation_6d_round_trip_and_geodesic():
    rng = np.random.default_rng(3)
    Rs = np.stack([random_rotation(rng) for _ in range(20)])
    R6 = _t(Rs)[..., :, :2].transpose(-1, -2).reshape(20, 6)  # columns x then y
    assert torch.allclose(rotation_6d_to_matrix(R6), _t(Rs), atol=1e-12)  # float64 Gram-Schmidt of a rotation
    Qs = np.stack([random_rotation(rng) for _ in range(20)])
    ang = geodesic_angle(_t(Rs), _t(Qs)).numpy()
    ref = [rotation_angle(a, b) for a, b in zip(Rs, Qs)]
    assert np.allclose(ang, ref, atol=1e-6)  # the eps under the sqrt shifts angles by <= 1e-6 rad


def test_geodesic_known_answers_and_finite_gradients():
    I = torch.eye(3, dtype=torch.float64)
    assert float(geodesic_angle(I, I)) < 2e-6  # sqrt(1e-12) floor
    R90 = _t(so3_exp([0.0, 0.0, math.pi / 2]))
    assert abs(float(geodesic_angle(I, R90)) - math.pi / 2) < 1e-9  # exact angle, no eps effect away from 0
    R180 = _t(so3_exp([math.pi, 0.0, 0.0]))
    assert abs(float(geodesic_angle(I, R180)) - math.pi) < 1e-6  # sin floor 1e-6 near pi
    for target in (I, R90, R180):
        x = torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], dtype=torch.float64, requires_grad=True)
        geodesic_angle(rotation_6d_to_matrix(x), target).backward()
        assert x.grad is not None and bool(torch.isfinite(x.grad).all())


def test_symmetric_rotation_error():
    rng = np.random.default_rng(4)
    R = _t(random_rotation(rng))
    about_y = R @ _t(so3_exp([0.0, 1.1, 0.0]))
    about_x = R @ _t(so3_exp([0.7, 0.0, 0.0]))
    flip_y = R @ _t(np.diag([-1.0, 1.0, -1.0]))
    flip_z = R @ _t(np.diag([-1.0, -1.0, 1.0]))
    tilt = R @ _t(so3_exp([0.3, 0.0, 0.0]))

    def err(pred, tag):
        return float(symmetric_rotation_error(pred, R, symmetry_codes([tag])[0]))

    assert err(about_y, "y_continuous") < 1e-5  # the sqrt eps floor
    assert abs(err(about_y, "none") - 1.1) < 1e-9
    assert err(about_x, "x_continuous") < 1e-5
    assert err(R @ _t(np.diag([1.0, -1.0, -1.0])) @ _t(so3_exp([0.4, 0, 0])), "x_continuous") < 1e-5  # flip
    assert err(flip_z, "box") < 1e-5 and err(flip_y, "y_2fold") < 1e-5
    assert abs(err(flip_z, "y_2fold") - math.pi) < 1e-5
    assert err(tilt, "spherical") == 0.0
    assert abs(err(tilt, "y_continuous") - 0.3) < 1e-9  # a tilt moves the y axis by its full angle
    with pytest.raises(UnknownNameError, match="y_continuous"):
        symmetry_codes(["cylinder"])


def test_chamfer_known_values():
    a = torch.rand(2, 50, 3, dtype=torch.float64)
    assert torch.allclose(chamfer_squared(a, a), torch.zeros(2, dtype=torch.float64))
    shifted = a + torch.tensor([0.0, 0.0, 0.01], dtype=torch.float64)
    b = torch.tensor([[[0.0, 0.0, 0.0]]], dtype=torch.float64)
    c = torch.tensor([[[0.0, 0.0, 0.1], [0.0, 0.0, 0.3]]], dtype=torch.float64)
    # a->b: 0.01 + 0.09 over 2 = 0.05 ; b->a: nearest 0.01
    assert torch.allclose(chamfer_squared(c, b), torch.tensor([0.06], dtype=torch.float64))
    assert float(chamfer_squared(a, shifted).max()) <= 2 * 0.01**2 + 1e-15  # at most the shift both ways


def _pose_batch(R_pred, t_pred, size_pred, R_true, t_true, size_true, symmetry="none", n=1):
    def rep(x):
        return _t(x)[None, None].expand(1, n, *np.shape(x)).clone()

    prior = torch.rand(1, 200, 3, dtype=torch.float64) - 0.5
    R, t, s = rep(R_true), rep(t_true), rep(size_true)
    obs = (prior[:, None] * s[:, :, None]) @ R.transpose(-1, -2) + t[:, :, None]
    out = {"R": rep(R_pred), "t": rep(t_pred), "size": rep(size_pred)}
    return pose_loss(out, R, t, s, symmetry_codes([symmetry]), obs, prior, torch.ones(1, n, dtype=torch.bool))


def test_pose_loss_hand_built_cases():
    I, t, s = np.eye(3), np.array([0.1, 0.0, 0.8]), np.array([0.1, 0.2, 0.05])
    zero = _pose_batch(I, t, s, I, t, s, n=3)
    for k in ("translation", "scale", "temporal", "geo"):
        assert float(zero[k]) < 1e-12, k  # exact pose, exact observation
    for k in ("rotation", "pose"):
        assert float(zero[k]) < 1e-6, k  # the geodesic's sqrt eps floor (5e-7 rad)
    R90 = so3_exp([0.0, 0.0, math.pi / 2])
    rot = _pose_batch(R90, t, s, I, t, s)
    assert abs(float(rot["rotation"]) - math.pi / 2) < 1e-9
    off = _pose_batch(I, t + np.array([0.01, -0.02, 0.0]), s + np.array([0.0, 0.0, 0.03]), I, t, s)
    assert abs(float(off["translation"]) - 0.03) < 1e-12 and abs(float(off["scale"]) - 0.03) < 1e-12
    assert float(off["geo"]) > 0.0
    w = off["pose"] + 0.5 * off["temporal"] + 10.0 * off["geo"]
    assert abs(float(off["loss"]) - float(w)) < 1e-12
    # y-symmetric object: a turn about y costs nothing
    sym = _pose_batch(so3_exp([0.0, 0.9, 0.0]), t, s, I, t, s, symmetry="y_continuous")
    assert float(sym["rotation"]) < 1e-5


def test_temporal_loss_counts_adjacent_changes():
    torch.manual_seed(5)
    n = 3
    R = torch.eye(3, dtype=torch.float64).expand(1, n, 3, 3).clone()
    t = torch.tensor([[[0.0, 0, 0.8], [0.01, 0, 0.8], [0.01, 0.02, 0.8]]], dtype=torch.float64)
    s = torch.full((1, n, 3), 0.1, dtype=torch.float64)
    pts = torch.rand(1, n, 10, 3, dtype=torch.float64)
    out = pose_loss(
        {"R": R, "t": t, "size": s},
        R,
        t,
        s,
        symmetry_codes(["none"]),
        pts,
        torch.rand(1, 8, 3).double(),
        torch.ones(1, n, dtype=torch.bool),
    )
    # 0.01^2 + 0.02^2 plus the two rotation floors (5e-7 rad)^2
    assert abs(float(out["temporal"]) - 5e-4) < 1e-10
