"""The network as a pose head: inference preprocessing equals the training pipeline's (`data.collate`), poses
come out per frame, frames without points stay None, and bad input is refused."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
import torch

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import robust_descriptor
from prompose_grasp.perception.network import ObjectTrack, ProMPoseNet, collate, network_config
from prompose_grasp.perception.network.pose_head import MaskedFrame, NetworkPoseHead

torch.set_num_threads(1)
TINY = network_config("tiny")


class SeededTextFeatures:
    """Frozen-encoder stand-in: fixed random token features per prompt (so the test needs no MiniLM)."""

    dim = TINY.text_dim

    def encode_tokens(self, prompt: str) -> np.ndarray:
        rng = np.random.default_rng(zlib.crc32(prompt.encode()))
        return rng.normal(size=(4, self.dim)).astype(np.float32)


@pytest.fixture(scope="module")
def head() -> NetworkPoseHead:
    torch.manual_seed(0)
    return NetworkPoseHead(ProMPoseNet(TINY), SeededTextFeatures())


def _frame(shift_px: int = 0, seed: int = 0) -> MaskedFrame:
    """A 120 x 160 frame: a tilted 6 x 4 cm patch 0.6 m away on a far background, with its mask."""
    intr = CameraIntrinsics(150.0, 150.0, 79.5, 59.5, 160, 120)
    v, u = np.mgrid[0:120, 0:160]
    depth = np.full((120, 160), 1.5)
    mask = (abs(u - 80 - shift_px) < 15) & (abs(v - 60) < 10)
    depth[mask] = 0.6 + 0.002 * (u[mask] - 80)  # tilted: the points span all three axes
    rgb = np.random.default_rng(seed).integers(0, 255, size=(120, 160, 3), dtype=np.uint8)
    return MaskedFrame(rgb, depth, intr, mask)


def test_prepare_samples_the_masked_points(head):
    p = head.prepare(_frame())
    assert p is not None
    assert p.points.shape == (TINY.observed_points, 3) and p.crop.shape == (TINY.crop_px, TINY.crop_px, 3)
    # every sampled point is on the patch (depth 0.57-0.63 m), none from the 1.5 m background
    assert float(p.points[:, 2].max()) < 0.64 and float(p.points[:, 2].min()) > 0.56
    np.testing.assert_allclose(p.descriptor, robust_descriptor(p.points).vector, rtol=1e-5, atol=1e-7)
    f = _frame()
    assert head.prepare(MaskedFrame(f.rgb, f.depth_m, f.intrinsics, np.zeros_like(f.mask))) is None


def test_predict_matches_the_training_batch_path(head):
    frames = [head.prepare(_frame(shift_px=s, seed=s)) for s in (0, 3, 6)]
    prior = np.random.default_rng(1).uniform(-0.5, 0.5, size=(TINY.prior_points, 3)).astype(np.float32)
    poses = head.predict([*frames, None], "a red box", prior)
    assert len(poses) == 4 and poses[3] is None
    # The same frames through the training collate: the track's invalid 4th frame repeats the 3rd.
    track = ObjectTrack(
        scene="s",
        instance_id=1,
        category="box",
        prompt="a red box",
        symmetry="none",
        crops=np.stack([f.crop for f in [*frames, frames[2]]]),
        points=np.stack([f.points for f in [*frames, frames[2]]]),
        frame_valid=np.array([True, True, True, False]),
        R_cam_obj=np.tile(np.eye(3, dtype=np.float32), (4, 1, 1)),
        t_cam_obj_m=np.zeros((4, 3), np.float32),
        size_m=np.ones((4, 3), np.float32),
        text_tokens=SeededTextFeatures().encode_tokens("a red box"),
        prior_points=prior,
    )
    batch = collate([track], [(0, 0)], TINY.window)
    with torch.no_grad():
        ref = head.model(**batch.inputs())
    for i in range(3):
        # same float32 network on the same tensors, different stacking order only: agreement to rounding
        np.testing.assert_allclose(poses[i].R, ref["R"][0, i].numpy(), atol=1e-5)
        np.testing.assert_allclose(poses[i].t, ref["t"][0, i].numpy(), atol=1e-6)
        np.testing.assert_allclose(poses[i].size, ref["size"][0, i].numpy(), rtol=1e-5)


def test_prior_of_another_size_is_resampled(head):
    frames = [head.prepare(_frame())]
    big = np.random.default_rng(2).uniform(-0.5, 0.5, size=(5000, 3))
    (pose,) = head.predict(frames, "a box", big)
    assert pose is not None and np.all(pose.size > 0)


def test_bad_input_is_refused(head):
    frames = [head.prepare(_frame())]
    prior = np.zeros((TINY.prior_points, 3))
    with pytest.raises(InvalidInputError):
        head.predict([], "a box", prior)
    with pytest.raises(InvalidInputError):
        head.predict(frames, "  ", prior)
    with pytest.raises(InvalidInputError):
        head.predict(frames, "a box", np.zeros((10, 2)))
    with pytest.raises(InvalidInputError):
        head.predict([None, None], "a box", prior)
    with pytest.raises(InvalidInputError):
        NetworkPoseHead(head.model, type("Narrow", (), {"dim": 7})())


@pytest.mark.sim
def test_shipped_network_is_trained_and_serves_as_the_estimators_head():
    from grounding_scene import render_scene

    from prompose_grasp import ProMPose
    from prompose_grasp.perception.network import SHIPPED_WEIGHTS
    from prompose_grasp.perception.network.checkpoint import load_checkpoint
    from prompose_grasp.robot import RGBDFrame

    ckpt = load_checkpoint(SHIPPED_WEIGHTS)
    assert "optimizer" not in ckpt and "trained_on" in ckpt and "command" in ckpt  # shipped, with provenance
    scene = render_scene()
    frame = RGBDFrame(scene.rgb, scene.depth_m, scene.intrinsics, timestamp_s=0.0)
    estimator = ProMPose.default(network_weights=str(SHIPPED_WEIGHTS))
    trained = estimator.network
    assert trained is not None
    assert trained.model.config == network_config("tiny", text_dim=trained.model.config.text_dim)
    torch.manual_seed(0)
    untrained = NetworkPoseHead(ProMPoseNet(trained.model.config), trained.text_encoder)
    for name, prompt in (("box", "the blue box"), ("can", "the yellow can"), ("bowl", "the green bowl")):
        mask = scene.gt_mask == scene.ids[name]
        gt = scene.gt_poses[name]
        prior = estimator.priors.generate(prompt)
        masked = MaskedFrame(frame.rgb, frame.depth_m, frame.intrinsics, mask)
        (p_trained,) = trained.predict([trained.prepare(masked)], prompt, prior.points)
        (p_untrained,) = untrained.predict([untrained.prepare(masked)], prompt, prior.points)
        assert p_trained is not None and p_untrained is not None
        # Training shows: the box overlaps better than the same network untrained (measured 0.38-0.57 vs
        # 0.30-0.36), and the up axis is learned (14-16 deg off the table normal vs 33 deg untrained).
        assert p_trained.iou(gt) > p_untrained.iou(gt), name
        assert np.degrees(np.arccos(abs(p_trained.R[:, 1] @ scene.up_cam))) < 25.0, name
        est = estimator.estimate(frame, prompt, mask=mask)
        assert "network" in est.timings_ms
        # the network's pose refined by the fit (one hypothesis from it): measured IoU 0.48-0.89
        assert est.pose.iou(gt) > 0.4, name
