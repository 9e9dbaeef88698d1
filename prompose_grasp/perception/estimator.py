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
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prompose_grasp.errors import AmbiguousObjectError, InvalidInputError, ObjectNotFoundError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.pointcloud import outline_corrected_points, valid_depth_mask
from prompose_grasp.perception.estimate import Estimate, plane_vector
from prompose_grasp.perception.fit import FitConfig, SceneView, fit_pose
from prompose_grasp.perception.grounding import Candidate, Grounder, GroundingResult, SupportPlane
from prompose_grasp.perception.grounding.language import check_prompt
from prompose_grasp.perception.grounding.plane import plane_under_object
from prompose_grasp.perception.priors import PriorLibrary, ShapePrior
from prompose_grasp.recorder import NULL_RECORDER, Recorder
from prompose_grasp.robot.interfaces import RGBDFrame

if TYPE_CHECKING:
    from prompose_grasp.perception.network.pose_head import NetworkPoseHead

__all__ = ["Estimate", "EstimatorConfig", "ProMPose"]

logger = logging.getLogger(__name__)


def _count(value: object, name: str, minimum: int) -> int:
    """`value` as an int >= `minimum`; a bool, a str or a float is refused (saying what is accepted)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InvalidInputError(f"{name} must be an integer >= {minimum}, got {value!r:.40}")
    if value < minimum:
        raise InvalidInputError(f"{name} must be an integer >= {minimum}, got {value}")
    return int(value)


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of the estimator facade.

    Attributes:
        max_objects: how many grounding candidates `estimate_all` turns into estimates (best first).
        min_points: a candidate with fewer valid depth points than this is skipped: below ~50 points a
            9-DoF fit is underdetermined against sensor noise.
        max_object_size_m: a fitted box with a side longer than this [m] is no object the cell can pick,
            and is not returned (`estimate_all` leaves it out, `estimate` raises `ObjectNotFoundError` when
            nothing else is left, a tracked frame counts as a lost track). 3 m: more than the diameter of
            the workspace of the largest arm here (UR10e, 1.3 m reach); such a box comes from a mask that
            spans the scene (the table, the floor, a whole-image mask), not from an object.
    """

    max_objects: int = 3
    min_points: int = 50
    max_object_size_m: float = 3.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "max_objects", _count(self.max_objects, "EstimatorConfig.max_objects", 1))
        object.__setattr__(self, "min_points", _count(self.min_points, "EstimatorConfig.min_points", 4))
        size = self.max_object_size_m
        if isinstance(size, bool) or not isinstance(size, int | float) or not 0.0 < size < math.inf:
            raise InvalidInputError(
                f"EstimatorConfig.max_object_size_m must be a positive finite number [m], got {size!r}"
            )


#: Library priors kept by prompt (`ProMPose._generate_prior`): a robot's vocabulary of objects, not more.
_MAX_KEPT_PRIORS = 64


def _check_prompt(prompt: str) -> str:
    """The prompt NFKC-normalised and stripped; refused when blank or without a Latin letter."""
    return check_prompt(prompt)


def _check_prior(prior: object) -> ShapePrior | None:
    if prior is not None and not isinstance(prior, ShapePrior):
        raise InvalidInputError(
            f"prior must be a ShapePrior (or None: generated from the prompt), got {type(prior).__name__}"
        )
    return prior


def _check_frame(frame: RGBDFrame) -> RGBDFrame:
    if not isinstance(frame, RGBDFrame):
        raise InvalidInputError(
            f"expected a prompose_grasp.robot.RGBDFrame (rgb, depth_m, intrinsics, timestamp_s), "
            f"got {type(frame).__name__}"
        )
    if not valid_depth_mask(frame.depth_m).any():
        raise InvalidInputError("the depth image has no valid reading (all zero, NaN or below 1 mm)")
    return frame


def _size_text(pose: Pose9D, bound_m: float) -> str:
    """A box's longest side against the size bound: "4.7 m long (more than max_object_size_m = 3 m)"."""
    return (
        f"{float(np.max(pose.size)):.3g} m long (more than EstimatorConfig.max_object_size_m = {bound_m:g} m)"
    )


def _too_large(dropped: list[Estimate], bound_m: float) -> str:
    """The note an `ObjectNotFoundError` gets when candidates were left out as too large, else ""."""
    if not dropped:
        return ""
    longest = max(dropped, key=lambda e: float(np.max(e.pose.size)))
    size = _size_text(longest.pose, bound_m)
    return f" ({len(dropped)} candidate(s) left out as too large to be an object: {size})"


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
        recorder: Recorder | None = None,
    ):
        self.grounder = grounder
        #: what each frame's grounding and estimates are recorded into (`prompose_grasp.recorder`; the
        #: default records nothing)
        self.recorder = recorder or NULL_RECORDER
        self.priors = priors
        self.fit_config = fit_config or FitConfig()
        self.config = config or EstimatorConfig()
        self.network = network
        # library priors by prompt (see `_generate_prior`)
        self._library_priors: dict[str, ShapePrior] = {}

    @classmethod
    def default(
        cls, device: str = "cpu", network_weights: str | None = None, recorder: Recorder | None = None
    ) -> ProMPose:
        """The embedded offline defaults: geometric grounding scored with MiniLM, the parametric prior
        library (shared by grounding and the prior), and the visibility-aware L_geo fit. Loading MiniLM and
        embedding the vocabularies takes a few seconds, once.

        `network_weights`: a network checkpoint (e.g. `network.SHIPPED_WEIGHTS`) whose pose starts each fit.
        `recorder`: records each frame's grounding candidates and estimates (e.g.
        `prompose_grasp.viz.RerunRecorder`); None records nothing.
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
        return cls(grounder, priors, network=network, recorder=recorder)

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
        dropped: list[Estimate] = []
        estimates = self._estimate_all(frame, prompt, prior, 1, 0.0, True, dropped)
        if not estimates or estimates[0].contenders == 0:
            note = _too_large(dropped, self.config.max_object_size_m)
            raise ObjectNotFoundError(f"no object in the frame matches {prompt!r}{note}")
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
        `max_objects`: an integer >= 1 (default `EstimatorConfig.max_objects`).
        `fit_contenders`: also fit every contender beyond `max_objects` (so that an ambiguous answer can show
        each of them).
        A fitted box longer than `EstimatorConfig.max_object_size_m` is left out (no object a gripper picks).

        Raises:
            InvalidInputError: bad frame, prompt, prior, `max_objects` or `min_score_ratio`.
        """
        if max_objects is not None:
            max_objects = _count(max_objects, "max_objects", 1)
        ratio = min_score_ratio
        if isinstance(ratio, bool) or not isinstance(ratio, int | float | np.floating) or not 0 <= ratio <= 1:
            raise InvalidInputError(f"min_score_ratio must be a number in [0, 1], got {ratio!r:.40}")
        return self._estimate_all(frame, prompt, prior, max_objects, float(ratio), bool(fit_contenders), [])

    def _estimate_all(
        self,
        frame: RGBDFrame,
        prompt: str,
        prior: ShapePrior | None,
        max_objects: int | None,
        min_score_ratio: float,
        fit_contenders: bool,
        dropped: list[Estimate],
    ) -> list[Estimate]:
        """`estimate_all` on checked arguments; the estimates left out as too large go to `dropped`."""
        t_total = time.perf_counter()
        prompt = _check_prompt(prompt)
        frame = _check_frame(frame)
        prior = _check_prior(prior)
        t0 = time.perf_counter()
        grounding = self.grounder.ground(frame.rgb, frame.depth_m, frame.intrinsics, prompt)
        grounding_ms = _ms(t0)
        self.recorder.grounding(frame, grounding)
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
            est = self._fit(
                candidate,
                points,
                prior,
                grounding,
                {"grounding": grounding_ms, "prior": prior_ms},
                network_input=(frame, prompt),
                scene=SceneView(frame.depth_m, frame.intrinsics, candidate.mask),
            )
            if self.too_large(est.pose):
                logger.info(
                    "candidate of %r left out: %s",
                    prompt,
                    _size_text(est.pose, self.config.max_object_size_m),
                )
                dropped.append(est)
                continue
            estimates.append(est)
        for est in estimates:
            est.timings_ms["total"] = _ms(t_total)
        self.recorder.estimates(frame, estimates)
        return estimates

    def track(
        self,
        frames: Iterable[RGBDFrame],
        prompt: str,
        prior: ShapePrior | None = None,
        mask: np.ndarray | None = None,
    ) -> Iterator[Estimate]:
        """Estimates frame after frame, refined over a sliding window (see `perception.tracker`).

        `frames`: an iterable (list, generator) of `RGBDFrame`, in capture order; for a single frame use
        `estimate`. `mask`: (H, W) bool pixels of the object in the first frame (your own segmentation); the
        track then starts from it instead of grounding the prompt (a lost track is grounded again).

        Raises:
            InvalidInputError: at the call (not at the first frame) for a prompt, prior or `frames` that is
            not an iterable of frames; for a frame of the sequence that is not an `RGBDFrame`, when it comes.
        """
        if isinstance(frames, RGBDFrame):
            raise InvalidInputError(
                "track takes a sequence of RGBDFrame (a list or an iterator), got one RGBDFrame; pass "
                "[frame], or use estimate(frame, prompt) for a single frame"
            )
        if isinstance(frames, str | bytes | np.ndarray) or not isinstance(frames, Iterable):
            raise InvalidInputError(
                f"frames must be an iterable (list, generator) of RGBDFrame, got {type(frames).__name__}"
            )
        return self._track(iter(frames), _check_prompt(prompt), _check_prior(prior), mask)

    def _track(
        self, frames: Iterator[RGBDFrame], prompt: str, prior: ShapePrior | None, mask: np.ndarray | None
    ) -> Iterator[Estimate]:
        from prompose_grasp.perception.tracker import Tracker

        tracker = Tracker(self, prompt, prior=prior)
        for k, frame in enumerate(frames):
            checked = _check_frame(frame)
            est = tracker.update(checked, mask=mask if k == 0 else None)
            self.recorder.estimates(checked, [est])
            yield est

    def too_large(self, pose: Pose9D) -> bool:
        """Whether a fitted box has a side longer than `EstimatorConfig.max_object_size_m`."""
        return bool(np.max(pose.size) > self.config.max_object_size_m)

    # ------------------------------------------------------------------------------------------------------

    def _estimate_masked(
        self, frame: RGBDFrame, prompt: str, mask: np.ndarray, prior: ShapePrior | None
    ) -> Estimate:
        t_total = time.perf_counter()
        prompt = _check_prompt(prompt)
        frame = _check_frame(frame)
        prior = _check_prior(prior)
        try:
            m = np.asarray(mask)
        except (TypeError, ValueError):
            m = np.asarray(None)  # refused below
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
        if self.too_large(est.pose):
            size = _size_text(est.pose, self.config.max_object_size_m)
            raise ObjectNotFoundError(
                f"the mask's fitted box is {size}: no object a gripper cell picks is that large; the mask "
                "covers more than one object (the table, the floor, the whole image)"
            )
        est.timings_ms["total"] = _ms(t_total)
        self.recorder.estimates(frame, [est])
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
        plane = grounding.support_plane
        if plane is None:
            prior = self.priors.generate(prompt, observation_points=points)
        else:  # a superquadric fallback stands on the support, as the object does
            prior = self.priors.generate(
                prompt, observation_points=points, up=plane.normal_cam, support_offset_m=plane.offset_m
            )
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
        on_top = candidate.attributes.support_height_m if candidate.attributes is not None else 0.0
        if support is not None and on_top > 0.0:  # it stands on another object's top face
            support = SupportPlane(support.normal_cam, support.offset_m - on_top, support.inlier_fraction)
        elif support is not None and scene is not None:  # the frame's plane, or a table top right under it
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
