"""The estimator's result types, shared by the estimator facade and the tracker (which must not import each
other both ways): `Estimate`, one object's estimate in one frame, and `plane_vector`, a support plane as
`fit_pose` takes it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import trimesh

from prompose_grasp.geometry import Pose9D
from prompose_grasp.perception.grounding import SupportPlane
from prompose_grasp.perception.grounding.types import CandidateAttributes
from prompose_grasp.perception.priors import ShapePrior

__all__ = ["Estimate", "plane_vector"]


@dataclass(frozen=True, eq=False)
class Estimate:
    """One object's estimate in one frame.

    Attributes:
        pose: the metric 9-DoF box in the camera frame.
        mask: (H, W) bool pixels of the object used for the fit.
        box_xyxy: (4,) int 2D box of the mask (x0, y0, x1, y1), inclusive pixel bounds.
        score: grounding score of the object against the prompt (higher is better; comparable within a frame;
            1 for a mask handed in). Always a number: a tracked update after the first frame carries the
            score of the grounding that started the track (or restarted it when it was lost), since it is
            the same object followed, not grounded again.
        prior: the canonical shape prior (unit box) and where it came from.
        fit_loss: the L_geo value at the solution [m^2].
        timings_ms: per-stage wall time {"grounding", "prior", "pose", "total"} [ms].
        frame_index: position in the sequence (0 for single frames).
        support_plane: the plane the object stands on, in the camera frame, when one was found.
        coverage: the fit's confidence in [0, 1] (`fit.mask_coverage`): the fraction of the fitted shape's
            camera-facing surface that the mask shows. Low when the object is cut by the image border or
            occluded (the hidden part of the box comes from the prior alone) or when the box outgrows its
            points; another view then helps. NaN on tracked updates after the first frame, which rest on the
            window's fused views rather than one mask.
        probability: the grounder's calibrated probability that this is the object the prompt names
            (`Candidate.probability`; 1 for a mask handed in, NaN where not computed).
        contenders: how many objects fit the prompt about equally well in this frame
            (`GroundingResult.contenders`): 1 clear, >= 2 ambiguous (`estimate` then raises
            `AmbiguousObjectError`), 0 nothing fits; -1 not judged.
        attributes: what the grounder measured of the object (colour, size class, shape family, extents),
            or None (a mask handed in).
        surface_cam: (M, 3) the object's seen surface in the camera frame [m] (`fit.seen_surface`: its
            mask's points above the support, dense and connected to the box; the grasp layer grasps narrow
            parts of it), or None where not computed.
    """

    pose: Pose9D
    mask: np.ndarray
    box_xyxy: np.ndarray
    score: float
    prior: ShapePrior
    fit_loss: float
    timings_ms: dict[str, float] = field(default_factory=dict)
    frame_index: int = 0
    support_plane: SupportPlane | None = None
    coverage: float = math.nan
    probability: float = math.nan
    contenders: int = -1
    attributes: CandidateAttributes | None = None
    surface_cam: np.ndarray | None = None

    @cached_property
    def mesh_cam(self) -> trimesh.Trimesh:
        """The prior mesh scaled to `pose.size` and posed in the camera frame [m] (a new mesh)."""
        mesh = self.prior.mesh.copy()
        mesh.vertices = self.pose.points_to_camera(mesh.vertices)
        return mesh

    def to_dict(self) -> dict[str, Any]:
        """The object fields of the `prompose-grasp estimate` JSON contract (DESIGN.md)."""
        return {
            **self.pose.to_dict(),
            "score": float(self.score),
            "probability": None if math.isnan(self.probability) else float(self.probability),
            "mask_pixels": int(np.count_nonzero(self.mask)),
            "prior": self.prior.name,
        }


def plane_vector(plane: SupportPlane | None) -> np.ndarray | None:
    """(4,) (nx, ny, nz, d) of a support plane, as `fit_pose` takes it; None when there is no plane."""
    return None if plane is None else np.append(plane.normal_cam, plane.offset_m)
