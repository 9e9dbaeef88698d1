"""`ProMPose`: RGB-D frames + a text prompt -> the metric 9-DoF box and the scaled prior mesh of the object.

The structure follows the paper's Algorithm 1 (shared/paper/ProM-Pose.txt, section 3):

1. ground the prompt in the frame (text -> mask)                         `perception.grounding`
2. generate the canonical shape prior once per sequence (text + frame)   `perception.priors`
3. back-project the masked depth and estimate R, t and the anisotropic
   size by minimising the paper's L_geo against the prior              `perception.fit`
4. refine over a sliding window of frames                               `perception.tracker`

Every component here is the embedded default that works offline on a CPU. The learned ProM-Pose network
(`perception.network`) slots in as another pose head: `ProMPose.default(network_weights=...)` starts each
single-frame fit from the network's pose (docs/network.md; the benchmark there says which head is better).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from prompose_grasp.errors import AmbiguousObjectError, InvalidInputError, ObjectNotFoundError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.pointcloud import outline_corrected_points, valid_depth_mask
from prompose_grasp.perception.fit import FitConfig, SceneView, fit_pose
from prompose_grasp.perception.grounding import Candidate, Grounder, GroundingResult, SupportPlane
from prompose_grasp.perception.grounding.plane import plane_under_object
from prompose_grasp.perception.grounding.types import CandidateAttributes
from prompose_grasp.perception.priors import PriorLibrary, ShapePrior
from prompose_grasp.robot.interfaces import RGBDFrame

if TYPE_CHECKING:
    from prompose_grasp.perception.network.pose_head import NetworkPoseHead

__all__ = ["Estimate", "EstimatorConfig", "ProMPose"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of the estimator facade.

    Attributes:
        max_objects: how many grounding candidates `estimate_all` turns into estimates (best first).
        min_points: a candidate with fewer valid depth points than this is skipped: below ~50 points a
            9-DoF fit is underdetermined against sensor noise.
    """

    max_objects: int = 3
    min_points: int = 50

    def __post_init__(self) -> None:
        if self.max_objects < 1 or self.min_points < 4:
            raise InvalidInputError("EstimatorConfig needs max_objects >= 1 and min_points >= 4")


@dataclass(frozen=True, eq=False)
class Estimate:
    """One object's estimate in one frame.

    Attributes:
        pose: the metric 9-DoF box in the camera frame.
        mask: (H, W) bool pixels of the object used for the fit.
        box_xyxy: (4,) int 2D box of the mask (x0, y0, x1, y1), inclusive pixel bounds.
        score: grounding score of the object against the prompt (higher is better; comparable within a frame).
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


#: Library priors kept by prompt (`ProMPose._generate_prior`): a robot's vocabulary of objects, not more.
_MAX_KEPT_PRIORS = 64


def _check_prompt(prompt: str) -> str:
    if not isinstance(prompt, str) or not prompt.strip():
        raise InvalidInputError(f"prompt must be a non-empty string naming the object, got {prompt!r}")
    return prompt.strip()


def _check_frame(frame: RGBDFrame) -> RGBDFrame:
    if not isinstance(frame, RGBDFrame):
        raise InvalidInputError(
            f"expected a prompose_grasp.robot.RGBDFrame (rgb, depth_m, intrinsics, timestamp_s), "
            f"got {type(frame).__name__}"
        )
    if not valid_depth_mask(frame.depth_m).any():
        raise InvalidInputError("the depth image has no valid reading (all zero, NaN or below 1 mm)")
    return frame


def plane_vector(plane: SupportPlane | None) -> np.ndarray | None:
    """(4,) (nx, ny, nz, d) of a support plane, as `fit_pose` takes it; None when there is no plane."""
    return None if plane is None else np.append(plane.normal_cam, plane.offset_m)


def _ms(t0: float) -> float:
    return 1e3 * (time.perf_counter() - t0)


class ProMPose:
    """The estimator: ground, prior, fit, track. Build it with `ProMPose.default()`.

    >>> estimator = ProMPose.default()  # doctest: +SKIP
    >>> est = estimator.estimate(frame, "the yellow carton")  # doctest: +SKIP
    >>> est.pose.size, est.mesh_cam  # doctest: +SKIP

    The default pose head is the test-time L_geo fit of the canonical prior (`perception.fit`), multi-
    hypothesis from the observation's axes: on the unseen-category benchmark (docs/benchmarks.md, "network")
    it beats the shipped network and the network followed by the fit, so `default()` uses it. With `network`
    (a `NetworkPoseHead`), each single-frame fit starts from the network's pose instead (one hypothesis).
    """

    def __init__(
        self,
        grounder: Grounder,
        priors: PriorLibrary,
        fit_config: FitConfig | None = None,
        config: EstimatorConfig | None = None,
        network: NetworkPoseHead | None = None,
    ):
        self.grounder = grounder
        self.priors = priors
        self.fit_config = fit_config or FitConfig()
        self.config = config or EstimatorConfig()
        self.network = network
        # library priors by prompt (see `_generate_prior`)
        self._library_priors: dict[str, ShapePrior] = {}

    @classmethod
    def default(cls, device: str = "cpu", network_weights: str | None = None) -> ProMPose:
        """The embedded offline defaults: geometric grounding scored with MiniLM, the parametric prior
        library (shared by grounding and the prior), and the visibility-aware L_geo fit. Loading MiniLM and
        embedding the vocabularies takes a few seconds, once.

        `network_weights`: a network checkpoint (e.g. `network.SHIPPED_WEIGHTS`) whose pose starts each fit.
        """
        from prompose_grasp.perception.text import default_text_encoder

        encoder = default_text_encoder(device)
        priors = PriorLibrary(encoder=encoder)
        grounder = Grounder(text_encoder=encoder, priors=priors)
        # Embed the closed description vocabularies now, so the first frame pays only for its own prompt.
        grounder.warm_up()
        network = None
        if network_weights is not None:
            from prompose_grasp.perception.network.pose_head import NetworkPoseHead

            network = NetworkPoseHead.load(network_weights, encoder, device)
        return cls(grounder, priors, network=network)

    # ------------------------------------------------------------------------------------------------------

    def estimate(
        self,
        frame: RGBDFrame,
        prompt: str,
        prior: ShapePrior | None = None,
        mask: np.ndarray | None = None,
    ) -> Estimate:
        """The best-matching object's estimate in one frame.

        Args:
            frame: colour, depth [m] and intrinsics.
            prompt: the object phrase ("the mug left of the bowl").
            prior: a canonical prior to use instead of generating one (e.g. from a CAD mesh).
            mask: (H, W) bool pixels of the object when you have your own segmentation; grounding is then
                skipped (the support plane is still found) and the estimate's score is 1.
        Raises:
            InvalidInputError: bad frame, prompt or mask.
            ObjectNotFoundError: nothing in the frame could be the object.
            AmbiguousObjectError: several objects fit the prompt about equally well (its `estimates`, best
                first, say which); a narrower prompt tells them apart.
        """
        if mask is not None:
            return self._estimate_masked(frame, prompt, mask, prior)
        estimates = self.estimate_all(frame, prompt, prior=prior, max_objects=1, fit_contenders=True)
        if not estimates or estimates[0].contenders == 0:
            raise ObjectNotFoundError(f"no object in the frame matches {prompt!r}")
        if estimates[0].contenders >= 2:
            raise AmbiguousObjectError(prompt, estimates[: estimates[0].contenders])
        return estimates[0]

    def estimate_all(
        self,
        frame: RGBDFrame,
        prompt: str,
        prior: ShapePrior | None = None,
        max_objects: int | None = None,
        min_score_ratio: float = 0.0,
        fit_contenders: bool = False,
    ) -> list[Estimate]:
        """Estimates of the best `max_objects` candidates, best first; an empty list when nothing matches.

        Every estimate carries its `probability` and the frame's `contenders` (ambiguity is the caller's
        to act on here; `estimate` raises for it).

        `min_score_ratio`: candidates whose grounding score is below this fraction of the best candidate's are
        not fitted (a caller that drops them anyway saves their fit, ~0.3 s each on 2 cores).
        `fit_contenders`: also fit every contender beyond `max_objects` (so that an ambiguous answer can show
        each of them).
        """
        t_total = time.perf_counter()
        prompt = _check_prompt(prompt)
        frame = _check_frame(frame)
        t0 = time.perf_counter()
        grounding = self.grounder.ground(frame.rgb, frame.depth_m, frame.intrinsics, prompt)
        grounding_ms = _ms(t0)
        estimates: list[Estimate] = []
        n = max_objects or self.config.max_objects
        if fit_contenders:
            n = max(n, grounding.contenders)
        candidates = grounding.candidates[:n]
        if candidates:
            floor = min_score_ratio * float(candidates[0].score)
            candidates = tuple(c for c in candidates if float(c.score) >= floor)
        for candidate in candidates:
            points = self.object_points(frame, candidate.mask)
            if len(points) < self.config.min_points:
                continue
            t0 = time.perf_counter()
            prior = prior or self._generate_prior(prompt, points, grounding)
            prior_ms = _ms(t0)
            estimates.append(
                self._fit(
                    candidate,
                    points,
                    prior,
                    grounding,
                    {"grounding": grounding_ms, "prior": prior_ms},
                    network_input=(frame, prompt),
                    scene=SceneView(frame.depth_m, frame.intrinsics, candidate.mask),
                )
            )
        for est in estimates:
            est.timings_ms["total"] = _ms(t_total)
        return estimates

    def track(
        self,
        frames: Iterable[RGBDFrame],
        prompt: str,
        prior: ShapePrior | None = None,
        mask: np.ndarray | None = None,
    ) -> Iterator[Estimate]:
        """Estimates frame after frame, refined over a sliding window (see `perception.tracker`).

        `mask`: (H, W) bool pixels of the object in the first frame (your own segmentation); the track then
        starts from it instead of grounding the prompt (a lost track is grounded again).
        """
        from prompose_grasp.perception.tracker import Tracker

        tracker = Tracker(self, _check_prompt(prompt), prior=prior)
        for k, frame in enumerate(frames):
            yield tracker.update(_check_frame(frame), mask=mask if k == 0 else None)

    # ------------------------------------------------------------------------------------------------------

    def _estimate_masked(
        self, frame: RGBDFrame, prompt: str, mask: np.ndarray, prior: ShapePrior | None
    ) -> Estimate:
        t_total = time.perf_counter()
        prompt = _check_prompt(prompt)
        frame = _check_frame(frame)
        m = np.asarray(mask)
        if m.shape != frame.depth_m.shape or m.dtype != np.bool_:
            raise InvalidInputError(
                f"mask must be a {frame.depth_m.shape} bool image, got {m.dtype} {m.shape}"
            )
        points = self.object_points(frame, m)
        if len(points) < self.config.min_points:
            raise ObjectNotFoundError(
                f"the mask holds {len(points)} valid depth points; the fit needs {self.config.min_points}"
            )
        t0 = time.perf_counter()
        plane = self.grounder.support_plane(frame.depth_m, frame.intrinsics)
        grounding = GroundingResult(prompt=prompt, candidates=(), support_plane=plane, contenders=1)
        ys, xs = np.nonzero(m)
        candidate = Candidate(m, np.array([xs.min(), ys.min(), xs.max(), ys.max()]), 1.0, probability=1.0)
        grounding_ms = _ms(t0)
        t0 = time.perf_counter()
        prior = prior or self._generate_prior(prompt, points, grounding)
        timings = {"grounding": grounding_ms, "prior": _ms(t0)}
        est = self._fit(
            candidate,
            points,
            prior,
            grounding,
            timings,
            network_input=(frame, prompt),
            scene=SceneView(frame.depth_m, frame.intrinsics, m),
        )
        est.timings_ms["total"] = _ms(t_total)
        return est

    def object_points(self, frame: RGBDFrame, mask: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points of the object's `mask` in `frame`, the fit's observation: the masked
        depth back-projected, its free outline half a pixel out (`outline_corrected_points`: pixel centres
        sample the surface, and the outermost lie half a pixel inside the outline)."""
        return outline_corrected_points(
            frame.depth_m, frame.intrinsics, mask, self.fit_config.occlusion_margin_m
        )

    def _generate_prior(self, prompt: str, points: np.ndarray, grounding: GroundingResult) -> ShapePrior:
        """The prior for `prompt`; a library family's prior is kept per prompt and handed out again.

        A library match depends on the prompt alone (the observation only shapes the superquadric
        fallback, which is not kept), and handing out the same object lets the fit reuse what it caches per
        prior (its farthest-point order of the surface samples, ~25 ms on an idle 2-core machine; the
        articulated variants of a laptop): a new track of an object named before starts faster.
        """
        kept = self._library_priors.get(prompt)
        if kept is not None:
            return kept
        up = None if grounding.support_plane is None else grounding.support_plane.normal_cam
        prior = self.priors.generate(prompt, observation_points=points, up=up)
        if prior.source.startswith("library:"):
            if len(self._library_priors) >= _MAX_KEPT_PRIORS:
                self._library_priors.pop(next(iter(self._library_priors)))  # the oldest prompt goes
            self._library_priors[prompt] = prior
        return prior

    def _fit(
        self,
        candidate: Candidate,
        points: np.ndarray,
        prior: ShapePrior,
        grounding: GroundingResult,
        timings_ms: dict[str, float],
        init: Pose9D | None = None,
        frame_index: int = 0,
        network_input: tuple[RGBDFrame, str] | None = None,
        scene: SceneView | None = None,
    ) -> Estimate:
        """Fit the prior to the candidate's points; `scene` (its depth image and mask) lets the fit ignore
        prior points the camera could not have seen (off the image, no reading, behind an occluder)."""
        t0 = time.perf_counter()
        if init is None and self.network is not None and network_input is not None:
            init = self._network_pose(candidate, prior, *network_input)
            timings_ms["network"] = _ms(t0)
            t0 = time.perf_counter()  # "pose" is the fit alone
        support = grounding.support_plane
        if support is not None and scene is not None:  # the frame's plane, or a table top right under it
            support = plane_under_object(support, points, scene.depth_m, scene.intrinsics, scene.mask)
        fit = fit_pose(
            points,
            prior,
            self.fit_config,
            init=init,
            support_plane_cam=plane_vector(support),
            scene=scene,
        )
        timings_ms["pose"] = _ms(t0)
        return Estimate(
            pose=fit.pose,
            mask=candidate.mask,
            box_xyxy=np.asarray(candidate.box_xyxy),
            score=float(candidate.score),
            prior=fit.prior or prior,  # an articulated variant (laptop screen angle) when one won
            fit_loss=float(fit.loss) if math.isfinite(fit.loss) else math.inf,
            timings_ms=timings_ms,
            frame_index=frame_index,
            support_plane=support,
            coverage=fit.coverage,
            probability=float(candidate.probability),
            contenders=int(grounding.contenders),
            attributes=candidate.attributes,
            surface_cam=fit.surface_points,
        )

    def _network_pose(
        self, candidate: Candidate, prior: ShapePrior, frame: RGBDFrame, prompt: str
    ) -> Pose9D | None:
        """The network's pose of the candidate, or None when its mask holds too few points for the network
        (the fit then starts from the observation, as without a network)."""
        from prompose_grasp.perception.network.pose_head import MaskedFrame

        assert self.network is not None
        masked = MaskedFrame(frame.rgb, frame.depth_m, frame.intrinsics, candidate.mask)
        prepared = self.network.prepare(masked)
        if prepared is None:
            return None
        return self.network.predict([prepared], prompt, prior.points)[-1]
