"""Value types of language grounding: config, support plane, candidates and the result (all frozen)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from prompose_grasp.errors import InvalidInputError

__all__ = [
    "Candidate",
    "CandidateAttributes",
    "GroundingConfig",
    "GroundingResult",
    "GroundingTiming",
    "SupportPlane",
]


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class GroundingConfig:
    """Settings of the embedded grounder. Lengths in metres, angles in degrees, pixels as stated.

    Attributes:
        plane_stride_px: the support plane is fitted on every `plane_stride_px`-th pixel in both directions.
        segment_stride_px: objects are clustered on this pixel grid, then painted at full resolution.
        ransac_iterations: plane hypotheses drawn (3 points each).
        ransac_inlier_m: a point within this distance of a hypothesis plane is an inlier [m]. A D435-like
            sensor has sigma(z) = 1 mm + 3.7 mm/m^2 z^2, 4 mm at 0.9 m; 12 mm keeps ~99 % of a table's
            points up to ~1 m while a 3-point hypothesis still has to be roughly right to collect them.
        seed: seed of the RANSAC generator (results are deterministic for a given input).
        noise_sigma_a_m, noise_sigma_b_per_m: axial depth noise model sigma(z) = a + b z^2 [m] (defaults:
            RealSense D435-like, as in `sim/noise.py`).
        height_sigmas: a point is "above the plane" when its height exceeds this many sigma(z) ...
        min_height_m: ... and at least this [m]. 2.5 sigma at the tabletop distances of 0.6-0.9 m is
            5.6-10 mm (0.6 % of table pixels pass, as isolated specks the size filter removes); 8 mm is that
            band's middle, so the height cut is max(8 mm, 2.5 sigma(z)).
        max_height_m: points higher than this above the plane are not objects (people, shelves) [m].
        neighbour_gap_sigmas, neighbour_gap_min_m: two neighbouring grid points join when their 3D distance
            is below max(gap_min, k sigma(z)) plus the spacing a surface at 75 deg to the ray would show.
        colour_edge: neighbours whose colours differ by more than this (CIE Lab distance, 8-bit Lab units
            from OpenCV) are split: touching objects of different colour become separate candidates.
        wide_colour_edge: neighbours also split when the colours one grid step before and one step after
            them differ by more than this (a 4-cell baseline): a blurred edge, whose single steps all stay
            under `colour_edge`, no longer chains a dark laptop screen to the white wall behind it. inf
            turns it off.
        crease_sigmas, crease_cells: grid neighbours in a concave crease of the depth surface do not join
            (`segment.concave_creases`): a point is in one when it lies more than `crease_sigmas` sigma(z)
            behind the mean of its two neighbours `crease_cells` grid cells away, along any of four
            directions. Touching objects meet in such valleys (a can against a box, a box against a robot's
            base), one object's faces meet at convex edges. inf turns it off.
        min_segment_px: segments smaller than this many full-resolution pixels are merged into a touching
            segment or dropped.
        max_candidates: at most this many candidates are returned (the best ones).
        device: torch device of the text encoder.
    """

    plane_stride_px: int = 4
    segment_stride_px: int = 2
    ransac_iterations: int = 128
    ransac_inlier_m: float = 0.012
    seed: int = 0
    noise_sigma_a_m: float = 0.001
    noise_sigma_b_per_m: float = 0.0037
    height_sigmas: float = 2.5
    min_height_m: float = 0.008
    max_height_m: float = 0.6
    neighbour_gap_sigmas: float = 4.0
    neighbour_gap_min_m: float = 0.006
    colour_edge: float = 28.0
    wide_colour_edge: float = 40.0
    crease_sigmas: float = 6.0
    crease_cells: int = 8
    min_segment_px: int = 150
    max_candidates: int = 32
    device: str = "cpu"

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "device":
                if not isinstance(value, str) or not value.strip():
                    msg = f"GroundingConfig.device must be a torch device string, got {value!r}"
                    raise InvalidInputError(msg)
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InvalidInputError(f"GroundingConfig.{f.name} must be a number, got {value!r}")
            if f.name == "seed":
                continue
            if f.name in ("crease_sigmas", "wide_colour_edge") and value == math.inf:  # test off
                continue
            if not math.isfinite(value) or value <= 0:
                raise InvalidInputError(f"GroundingConfig.{f.name} must be finite and > 0, got {value!r}")
        ints: tuple[str, ...] = ("plane_stride_px", "segment_stride_px", "ransac_iterations")
        ints += ("min_segment_px", "max_candidates", "crease_cells")
        for name in ints:
            if not isinstance(getattr(self, name), int):
                raise InvalidInputError(f"GroundingConfig.{name} must be an int, got {getattr(self, name)!r}")
        if self.max_height_m <= self.min_height_m:
            raise InvalidInputError(
                f"GroundingConfig.max_height_m ({self.max_height_m}) must exceed "
                f"min_height_m ({self.min_height_m})"
            )

    def sigma_m(self, z_m: np.ndarray | float) -> np.ndarray | float:
        """Axial depth noise [m] at depth z [m]: a + b z^2."""
        return self.noise_sigma_a_m + self.noise_sigma_b_per_m * np.square(z_m)


@dataclass(frozen=True)
class SupportPlane:
    """The plane objects stand on, in the camera frame: points x with n . x + d = 0.

    Attributes:
        normal_cam: (3,) float64 unit normal, pointing to the side the camera is on ("up" for a table seen
            from above).
        offset_m: d [m]; the signed height of a point above the plane is n . x + d, so the camera's own
            height above the plane is d (> 0).
        inlier_fraction: share of the valid sampled points within the inlier distance, in [0, 1].
    """

    normal_cam: np.ndarray
    offset_m: float
    inlier_fraction: float

    def __post_init__(self) -> None:
        n = np.asarray(self.normal_cam, dtype=np.float64)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or abs(np.linalg.norm(n) - 1.0) > 1e-6:
            raise InvalidInputError(f"normal_cam must be a finite (3,) unit vector, got {self.normal_cam!r}")
        object.__setattr__(self, "normal_cam", _frozen(n))
        object.__setattr__(self, "offset_m", float(self.offset_m))
        object.__setattr__(self, "inlier_fraction", float(self.inlier_fraction))

    def height_m(self, points_cam: np.ndarray) -> np.ndarray:
        """Signed heights [m] of (..., 3) camera-frame points (positive on the camera's side)."""
        return np.asarray(points_cam, dtype=np.float64) @ self.normal_cam + self.offset_m


@dataclass(frozen=True)
class CandidateAttributes:
    """What the grounder saw of one candidate (all measured from the image, none from ground truth).

    Attributes:
        colour_name: dominant colour word of the fixed palette (`describe.PALETTE`).
        colour_rgb: (3,) uint8 median colour of the pixels of that colour.
        size_class: "small" | "medium" | "large" from the largest extent (`describe.SIZE_CLASSES`).
        shape_family: "box" | "cylinder" | "sphere" | "flat" | "elongated" | "irregular".
        centroid_cam: (3,) float64 mean of the candidate's points in the camera frame [m].
        extent_m: (3,) float64 visible extents [m] in the support-plane frame: footprint length, footprint
            width (length >= width) and height above what it stands on (`support_height_m`; full extents
            when no plane).
        num_pixels: pixels in the full-resolution mask.
        description: the generated phrase scored against the prompt ("a small yellow cylinder-shaped object").
        top_height_histogram: (HEIGHT_BINS,) float64 shares summing to 1 (empty when not measured): the
            candidate seen from above, the highest point of each footprint cell as a fraction of the height,
            histogrammed (`describe.top_height_histogram`); a box is all "top", a laptop mostly "low".
        handle_seen: a round candidate shows a handle (`describe.handle_seen`): a mug, not a cup.
        taper: log(r_upper / r_lower) of a round candidate's body (`describe.taper`): > 0 widening upwards
            (a paper cup), NaN when not measured.
        shape_family_alternative: "box" or "cylinder" when the box/cylinder test came out near its
            threshold (`describe.shape_families`): the shape score then weighs both; else None.
        support_height_m: height [m] above the support plane of the surface the candidate stands on: 0 on
            the plane, the top face of the object under it for one standing on another.
        outline_hidden: share of the mask's outline beyond which more of the candidate could be hidden
            (`describe.outline_hidden`): 0 when free space bounds it all round; 1 when not measured.
    """

    colour_name: str
    colour_rgb: np.ndarray
    size_class: str
    shape_family: str
    centroid_cam: np.ndarray
    extent_m: np.ndarray
    num_pixels: int
    description: str
    top_height_histogram: np.ndarray = field(default_factory=lambda: np.zeros(0))
    handle_seen: bool = False
    taper: float = float("nan")
    shape_family_alternative: str | None = None
    support_height_m: float = 0.0
    outline_hidden: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "colour_rgb", _frozen(np.asarray(self.colour_rgb, dtype=np.uint8)))
        object.__setattr__(
            self, "top_height_histogram", _frozen(np.asarray(self.top_height_histogram, dtype=np.float64))
        )
        object.__setattr__(self, "centroid_cam", _frozen(np.asarray(self.centroid_cam, dtype=np.float64)))
        object.__setattr__(self, "extent_m", _frozen(np.asarray(self.extent_m, dtype=np.float64)))


@dataclass(frozen=True)
class Candidate:
    """One grounded object.

    Attributes:
        mask: (H, W) bool, full image resolution.
        box_xyxy: (4,) int64 tight pixel box (x0, y0, x1, y1), inclusive of both corners' pixels.
        score: how well it matches the prompt; higher is better (in (0, 1) for the embedded grounder).
        attributes: measured attributes (None for grounders that do not measure them, e.g. the DINO adapter).
        probability: calibrated probability that this candidate is the object the prompt names (the
            candidates' probabilities sum to at most 1; `grounding.confidence`); NaN where not computed.
    """

    mask: np.ndarray
    box_xyxy: np.ndarray
    score: float
    attributes: CandidateAttributes | None = None
    probability: float = float("nan")

    def __post_init__(self) -> None:
        m = np.asarray(self.mask)
        if m.ndim != 2 or m.dtype != np.bool_:
            raise InvalidInputError(f"Candidate.mask must be an (H, W) bool image, got {m.dtype} {m.shape}")
        b = np.asarray(self.box_xyxy)
        if b.shape != (4,):
            raise InvalidInputError(f"Candidate.box_xyxy must have shape (4,), got {b.shape}")
        object.__setattr__(self, "mask", _frozen(m))
        object.__setattr__(self, "box_xyxy", _frozen(b.astype(np.int64)))
        object.__setattr__(self, "score", float(self.score))
        object.__setattr__(self, "probability", float(self.probability))


@dataclass(frozen=True)
class GroundingTiming:
    """Wall time of the stages [s]; `total_s` is the whole `ground` call."""

    plane_s: float = 0.0
    segment_s: float = 0.0
    describe_s: float = 0.0
    score_s: float = 0.0
    total_s: float = 0.0


@dataclass(frozen=True)
class GroundingResult:
    """The result of grounding one prompt in one RGB-D frame.

    Attributes:
        prompt: the prompt as given.
        candidates: best first (descending score).
        support_plane: the plane objects stand on, or None (no plane found, or the grounder does not fit one).
        timing: stage wall times.
        contenders: how many of the best candidates fit the prompt about equally well
            (`grounding.confidence`): 0 when none fits the words, 1 when one clearly wins, 2 or more when the
            prompt does not tell them apart (`ambiguous`). -1 where the grounder does not judge it.
    """

    prompt: str
    candidates: tuple[Candidate, ...]
    support_plane: SupportPlane | None
    timing: GroundingTiming = field(default_factory=GroundingTiming)
    contenders: int = -1

    @property
    def ambiguous(self) -> bool:
        """Two or more candidates fit the prompt about equally well: none should be chosen for it."""
        return self.contenders >= 2

    @property
    def margin(self) -> float:
        """The best candidate's probability minus the runner-up's (the best's alone with one candidate;
        NaN without candidates or probabilities)."""
        if not self.candidates:
            return float("nan")
        p = [c.probability for c in self.candidates[:2]]
        return p[0] - (p[1] if len(p) > 1 else 0.0)

    @property
    def best(self) -> Candidate | None:
        """The highest-scoring candidate, or None when there is none."""
        return self.candidates[0] if self.candidates else None
