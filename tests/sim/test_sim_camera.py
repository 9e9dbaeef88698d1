"""MuJoCo's projection equals `CameraIntrinsics.from_fovy`; depth is metric along the optical axis; frames."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.geometry.se3 import invert_T, make_T, so3_exp, transform_points
from sim.camera import T_CAMGL_CAM, CameraSpec, look_at, mujoco_intrinsics
from sim.scene_builder import SceneBuilder

pytestmark = pytest.mark.sim


def _plane_world(T_world_cam: np.ndarray, width=160, height=120, fovy=50.0):
    b = SceneBuilder("plane")
    floor = b.add_floor(size_m=(8.0, 8.0))
    b.add_camera(CameraSpec("cam", width, height, fovy, T_parent_cam=T_world_cam))
    return b.build(), floor


def test_depth_matches_analytic_plane_with_library_intrinsics():
    # an oblique view of the z = 0 plane: depth varies across the image, so any cx/cy or fy error shows up
    T_world_cam = make_T(so3_exp([np.pi - 0.45, 0.1, 0.2]), [0.1, 0.2, 1.0])
    world, _ = _plane_world(T_world_cam)
    with world:
        np.testing.assert_allclose(world.T_world_cam("cam"), T_world_cam, atol=1e-9)
        _, depth = world.render_clean("cam")
        K = world.intrinsics("cam")
        v, u = np.mgrid[0 : K.height, 0 : K.width]
        rays_cam = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, float)], axis=-1)
        R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
        z_true = -t[2] / (rays_cam @ R.T)[..., 2]  # ray z = 1 in cam, so the scale is the optical-axis depth
        # float32 depth buffer linearised by MuJoCo: 1e-5 m is far above its ~1e-7 m error at ~1 m range
        np.testing.assert_allclose(depth, z_true, atol=1e-5)
        # half a pixel of principal-point error would move depth by ~mm here: the check above excludes it
        assert K == mujoco_intrinsics(160, 120, 50.0)


def test_back_projected_points_lie_on_the_plane():
    T_world_cam = look_at([0.6, -0.8, 1.2], [0.0, 0.0, 0.0])
    world, _ = _plane_world(T_world_cam, 120, 90, 65.0)
    with world:
        _, depth = world.render_clean("cam")
        K = world.intrinsics("cam")
        from conftest import back_project

        pts_cam = back_project(depth, K.fx, K.fy, K.cx, K.cy, np.ones(depth.shape, bool))
        pts_world = transform_points(world.T_world_cam("cam"), pts_cam)
        assert len(pts_world) == depth.size
        np.testing.assert_allclose(pts_world[:, 2], 0.0, atol=2e-5)  # same depth-buffer precision, at ~2 m


def test_opencv_and_mujoco_camera_frames():
    np.testing.assert_array_equal(T_CAMGL_CAM @ T_CAMGL_CAM, np.eye(4))
    T = look_at([0.0, -1.0, 1.0], [0.0, 0.0, 0.0])
    z_world = T[:3, 2]
    np.testing.assert_allclose(z_world, np.array([0.0, 1.0, -1.0]) / np.sqrt(2.0), atol=1e-12)
    assert T[2, 1] < 0  # image down (+y) points down in the world


def test_wrist_camera_follows_its_mount():
    b = SceneBuilder("wrist")
    b.add_floor()
    T_world_flange = make_T(so3_exp([np.pi, 0.0, 0.0]), [0.0, 0.0, 1.0])
    b.add_mount_body("flange", T_world_flange)
    T_flange_cam = make_T(np.eye(3), [0.0, 0.05, 0.02])
    b.add_camera(CameraSpec("wrist", 64, 48, 60.0, T_parent_cam=T_flange_cam, parent_body="flange"))
    with b.build() as world:
        np.testing.assert_allclose(world.T_world_cam("wrist"), T_world_flange @ T_flange_cam, atol=1e-9)
        T2 = make_T(so3_exp([np.pi, 0.3, 0.0]), [0.2, 0.1, 0.8])
        world.set_mount_pose("flange", T2)
        np.testing.assert_allclose(world.T_world_cam("wrist"), T2 @ T_flange_cam, atol=1e-9)
        _, depth = world.render_clean("wrist")
        # looking down from ~0.8 m at the floor: the centre pixel's depth is the height over cos(tilt)
        T_cam = world.T_world_cam("wrist")
        expected = T_cam[2, 3] / -T_cam[2, 2]
        assert depth[23:25, 31:33].mean() == pytest.approx(expected, abs=0.01)  # 1 cm: half a pixel of slope
        assert np.allclose(invert_T(T_cam) @ T_cam, np.eye(4))
