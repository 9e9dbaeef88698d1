"""The embedded grounder: support plane, object candidates, their attributes, and scores for a prompt."""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from typing import Any

import cv2
import numpy as np

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import check_depth_units, depth_to_point_map, valid_depth_mask
from prompose_grasp.perception.grounding.confidence import ConfidenceModel, contenders, match_probabilities
from prompose_grasp.perception.grounding.describe import (
    PALETTE,
    SHAPE_FAMILIES,
    SIZE_CLASSES,
    describe_text,
    dominant_colour,
    handle_seen,
    outline_hidden,
    shape_families,
    shape_family,
    size_class,
    taper,
    top_height_cell_fraction,
    top_height_histogram,
)
from prompose_grasp.perception.grounding.language import ParsedPrompt, check_prompt, parse_prompt
from prompose_grasp.perception.grounding.plane import PlaneFrame, fit_support_plane
from prompose_grasp.perception.grounding.score import (
    FAMILY_TEXTS,
    SAME_MATCH,
    CandidateFeatures,
    NounPrior,
    RivalReadings,
    ScoringWeights,
    candidate_totals,
    score_of_total,
)
from prompose_grasp.perception.grounding.segment import Segment, segment_objects
from prompose_grasp.perception.grounding.types import (
    Candidate,
    CandidateAttributes,
    GroundingConfig,
    GroundingResult,
    GroundingTiming,
    SupportPlane,
)

__all__ = ["Grounder", "ground", "validate_frame"]

log = logging.getLogger(__name__)

#: Colour naming looks at no more than this many pixels of a mask (an even thinning): the palette shares are
#: then known to about +-1 % (binomial), far finer than the 40 % share the colour term asks for.
_MAX_COLOUR_PIXELS = 3000


def validate_frame(
    rgb: Any, depth_m: Any, intrinsics: Any, prompt: Any
) -> tuple[np.ndarray, np.ndarray, CameraIntrinsics, str]:
    """Check a grounding call's inputs and return them. Raises `InvalidInputError` saying what is wrong.

    Accepted: rgb (H, W, 3) uint8; depth_m (H, W) float32 or float64 metres with 0 / NaN for no reading and
    at least one valid reading, their median a distance an RGB-D camera measures (`check_depth_units`);
    intrinsics a `CameraIntrinsics` for (H, W); prompt a str with a word in Latin letters
    (`language.check_prompt`; returned NFKC-normalised).
    """
    if not isinstance(intrinsics, CameraIntrinsics):
        raise InvalidInputError(
            "intrinsics must be a prompose_grasp.geometry.CameraIntrinsics, got "
            f"{type(intrinsics).__name__}; build one with CameraIntrinsics(fx, fy, cx, cy, width, height) "
            "or CameraIntrinsics.from_K(K, width, height)"
        )
    prompt = check_prompt(prompt)
    if not isinstance(rgb, np.ndarray):
        raise InvalidInputError(f"rgb must be a numpy array (H, W, 3) uint8, got {type(rgb).__name__}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InvalidInputError(f"rgb must have shape (H, W, 3), got {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise InvalidInputError(f"rgb must be uint8 (0-255), got dtype {rgb.dtype}")
    if not isinstance(depth_m, np.ndarray):
        raise InvalidInputError(f"depth_m must be a numpy array (H, W) float32, got {type(depth_m).__name__}")
    if depth_m.ndim != 2:
        raise InvalidInputError(f"depth_m must have shape (H, W), got {depth_m.shape}")
    if depth_m.dtype not in (np.float32, np.float64):
        raise InvalidInputError(
            f"depth_m must be float32 metres, got dtype {depth_m.dtype}; convert integer depth first "
            "(e.g. uint16 millimetres: depth_m = raw.astype(np.float32) * 0.001)"
        )
    if rgb.shape[:2] != depth_m.shape:
        raise InvalidInputError(f"rgb is {rgb.shape[:2]} but depth_m is {depth_m.shape}; they must match")
    if depth_m.shape != intrinsics.shape:
        raise InvalidInputError(
            f"images are (H, W) = {depth_m.shape} but the intrinsics are for {intrinsics.shape}"
        )
    if not np.any(valid_depth_mask(depth_m)):
        raise InvalidInputError(
            "depth_m has no valid reading (every pixel is 0, negative, NaN or inf); check the depth stream "
            "and its scale (metres)"
        )
    check_depth_units(depth_m, "depth_m")
    return rgb, depth_m, intrinsics, prompt


class Grounder:
    """Text -> masks with the embedded default (support plane + clustering + attribute scoring).

    Args:
        config: segmentation and plane settings.
        text_encoder: any `perception.text.TextEncoder`; default: the shared MiniLM, loaded on first use.
        weights: score term weights (`score.ScoringWeights`).
        priors: a `perception.priors.PriorLibrary` whose families' typical sizes give the metric size term
            (share the estimator's); default: one built on first use with this grounder's text encoder
            (the priors package is imported then, not at module import: it pulls in trimesh).
        knowledge: a `perception.knowledge.ObjectKnowledge` (typical size, colour and shape by object name);
            default: the shipped table with this grounder's text encoder, built on first use.
        confidence: the calibration of the match probabilities and contenders (`confidence.ConfidenceModel`).

    The text encoder is only touched by `ground`; embeddings of descriptions and family sentences and the
    library family of each noun are cached.
    """

    def __init__(
        self,
        config: GroundingConfig | None = None,
        text_encoder: Any | None = None,
        weights: ScoringWeights | None = None,
        priors: Any | None = None,
        knowledge: Any | None = None,
        confidence: ConfidenceModel | None = None,
    ):
        if config is not None and not isinstance(config, GroundingConfig):
            raise InvalidInputError(f"config must be a GroundingConfig, got {type(config).__name__}")
        if weights is not None and not isinstance(weights, ScoringWeights):
            raise InvalidInputError(f"weights must be a ScoringWeights, got {type(weights).__name__}")
        if priors is not None and not (hasattr(priors, "match") and hasattr(priors, "family_prior")):
            raise InvalidInputError(
                "priors must be a perception.priors.PriorLibrary (with match and family_prior), "
                f"got {type(priors).__name__}"
            )
        if knowledge is not None and not hasattr(knowledge, "lookup"):
            raise InvalidInputError(
                f"knowledge must be a perception.knowledge.ObjectKnowledge, got {type(knowledge).__name__}"
            )
        if confidence is not None and not isinstance(confidence, ConfidenceModel):
            raise InvalidInputError(f"confidence must be a ConfidenceModel, got {type(confidence).__name__}")
        self.config = config or GroundingConfig()
        self.weights = weights or ScoringWeights()
        self.confidence = confidence or ConfidenceModel()
        self._knowledge = knowledge
        self._encoder = text_encoder
        self._priors = priors
        self._cache: dict[str, np.ndarray] = {}
        self._noun_priors: dict[str, NounPrior | None] = {}
        self._lock = threading.Lock()
        self._priors_lock = threading.Lock()

    @property
    def text_encoder(self) -> Any:
        """The sentence encoder (the shared MiniLM unless one was given), loaded on first access."""
        if self._encoder is None:
            from prompose_grasp.perception.text import default_text_encoder

            self._encoder = default_text_encoder(self.config.device)
        return self._encoder

    @property
    def priors(self) -> Any:
        """The prior library consulted for nouns' typical sizes (built on first access)."""
        with self._priors_lock:
            if self._priors is None:
                from prompose_grasp.perception.priors import PriorLibrary

                self._priors = PriorLibrary(encoder=self.text_encoder)
            return self._priors

    @property
    def knowledge(self) -> Any:
        """The object-knowledge table consulted for the named object's size, colours and shape (built on first
        access)."""
        with self._priors_lock:
            if self._knowledge is None:
                from prompose_grasp.perception.knowledge import ObjectKnowledge

                self._knowledge = ObjectKnowledge(self.text_encoder)
            return self._knowledge

    def warm_up(self) -> None:
        """Load the text encoder, embed every possible description, the shape-family sentences and the prior
        library's family names, and build every family's `NounPrior` (the rival term reads them all).

        Descriptions come from a closed vocabulary (3 sizes x 12 colours x 6 families = 216 phrases), so
        after this a first `ground` call only encodes the prompt's own phrases (one short batch).
        """
        phrases = [
            describe_text(size, colour, family)
            for size, _ in SIZE_CLASSES
            for colour in PALETTE
            for family in SHAPE_FAMILIES
        ]
        self._embed([*FAMILY_TEXTS.values(), *phrases, *self._family_names()])
        for name in ("object", *self._family_names()):  # the rival term reads every family (`_rivals`)
            self.noun_prior(name)
        self.knowledge.warm_up()

    def noun_prior(self, noun: str) -> NounPrior | None:
        """The library family `noun` names (its best match at or above the library's threshold), or None.

        Args:
            noun: a noun phrase ("mug", "soda can"); "" gives None.
        """
        if not isinstance(noun, str):
            raise InvalidInputError(f"noun must be a str, got {type(noun).__name__}")
        if noun in self._noun_priors:
            return self._noun_priors[noun]
        library = self.priors
        out = None
        if noun.strip():
            family, score = library.match(noun)[0]
            if score >= library.threshold:
                prior = library.family_prior(family)
                t = np.asarray(prior.typical_size_m, dtype=np.float64)
                # canonical frames are +y up: footprint (x, z) sorted, then the height y
                extent = np.array([max(t[0], t[2]), min(t[0], t[2]), t[1]])
                P = np.asarray(prior.points, dtype=np.float64) * t  # unit box -> metres, centred
                coords = np.column_stack([P[:, 0], P[:, 2], P[:, 1] + 0.5 * t[1]])
                out = NounPrior(
                    family,
                    float(score),
                    extent,
                    top_height_histogram(coords, t[1], extent[0]),
                    # the mesh seen all around, judged as a round thing: does the family carry a handle?
                    has_handle=handle_seen(coords, extent, "cylinder"),
                    # judged as a candidate would be: only a family whose mesh reads round has a taper
                    taper=taper(coords, extent, shape_family(coords, extent)),
                )
                out = self._sized_as_product(noun, out, prior.symmetry)
        with self._priors_lock:
            self._noun_priors[noun] = out
        return out

    def _sized_as_product(self, noun: str, prior: NounPrior, symmetry: str) -> NounPrior:
        """`prior` for a product the table and the library both name exactly that is not the family's own
        name ("cereal box", "soda can"): the family's typical size is every box's or can's, the table's
        entry that product's (score module docstring, "Object knowledge"). A family that rests on any face
        (box symmetry) has no typical size left: the entry's range stands alone. A round family stands on
        its base: the entry's two most alike extents are its footprint, the third its height. Any other
        family keeps its own (a handle or a lens makes the entry's extents no footprint)."""
        match = self.knowledge.lookup(noun)
        if (
            match is None
            or match.weight < 1.0
            or match.noun == prior.family
            or abs(match.similarity - prior.match_score) > SAME_MATCH
        ):
            return prior
        if symmetry == "box":
            return dataclasses.replace(prior, typical_extent_m=None)
        if symmetry != "y_continuous":
            return prior
        mid = 0.5 * (match.size_lo_m + match.size_hi_m)  # largest first
        # the two most alike (the smaller ratio of neighbours) are the footprint
        footprint_first = mid[0] / mid[1] < mid[1] / mid[2]
        typical = mid if footprint_first else mid[[1, 2, 0]]
        return dataclasses.replace(prior, typical_extent_m=typical)

    def _embed(self, texts: list[str]) -> np.ndarray:
        """(N, D) unit embeddings, cached per text (descriptions come from a small vocabulary)."""
        with self._lock:
            missing = list(dict.fromkeys(t for t in texts if t not in self._cache))
            if missing:
                for t, e in zip(missing, self.text_encoder.encode(missing)):
                    self._cache[t] = np.asarray(e, dtype=np.float64)
            return np.stack([self._cache[t] for t in texts])

    def _shape_prob(self, parsed: ParsedPrompt) -> dict[str, float] | None:
        """p(family | noun): softmax of the noun's similarity to the family sentences (None: generic noun)."""
        if parsed.generic:
            return None
        E = self._embed([parsed.noun, *FAMILY_TEXTS.values()])
        sims = E[1:] @ E[0]
        z = np.exp((sims - sims.max()) / self.weights.family_temperature)
        return dict(zip(FAMILY_TEXTS, (z / z.sum()).tolist()))

    def _attributes(
        self, rgb: np.ndarray, points_map: np.ndarray, seg: Segment, frame: PlaneFrame | None, focal_px: float
    ) -> tuple[CandidateAttributes, dict[str, float], np.ndarray]:
        pts = seg.points_cam
        # the segment's points lie on the clustering grid: this far apart at its median range
        spacing = self.config.segment_stride_px * float(np.median(pts[:, 2])) / focal_px if len(pts) else 0.0
        if frame is not None:
            coords = frame.coords(pts)
            coords[:, 2] -= seg.base_height_m  # heights above what it stands on
            rect = cv2.minAreaRect(coords[:, :2].astype(np.float32))
            a, b = sorted(rect[1], reverse=True)
            height = float(np.percentile(coords[:, 2], 98)) if len(coords) else 0.0
            extent = np.array([a, b, max(height, 0.0)])
            xy = coords[:, :2].mean(axis=0)
        else:  # no plane: principal axes; "height" is the smallest spread
            c = pts - pts.mean(axis=0)
            _, vecs = np.linalg.eigh(c.T @ c)
            coords = c @ vecs[:, ::-1]
            coords[:, 2] -= coords[:, 2].min()
            extent = np.ptp(coords, axis=0)
            xy = pts[:, [0, 2]].mean(axis=0)
        ys, xs = np.nonzero(seg.mask)
        step = max(1, len(ys) // _MAX_COLOUR_PIXELS)
        colour, colour_rgb, shares = dominant_colour(rgb[ys[::step], xs[::step]])
        size = size_class(extent)
        family, alternative = shape_families(coords, extent)
        cell = top_height_cell_fraction(float(extent[0]), spacing)
        tops = top_height_histogram(coords, float(extent[2]), float(extent[0]), cell)
        handle, body_taper = False, float("nan")
        if frame is not None:  # without a plane there is no footprint to find a handle around
            # on the whole mask's grid points: a handle often joins its body's mask only when the mask is
            # grown at full resolution, after clustering (`segment_objects`), so not in `seg.points_cam`
            s = self.config.segment_stride_px
            grid = points_map[::s, ::s][seg.mask[::s, ::s]]
            grid_coords = frame.coords(grid[np.isfinite(grid[:, 2])])
            grid_coords[:, 2] -= seg.base_height_m
            handle = handle_seen(grid_coords, extent, family)
            body_taper = taper(grid_coords, extent, family)
        attrs = CandidateAttributes(
            colour_name=colour,
            colour_rgb=colour_rgb,
            size_class=size,
            shape_family=family,
            centroid_cam=pts.mean(axis=0),
            extent_m=extent,
            num_pixels=len(ys),
            description=describe_text(size, colour, family),
            top_height_histogram=tops,
            handle_seen=handle,
            taper=body_taper,
            shape_family_alternative=alternative,
            support_height_m=seg.base_height_m,
            # without a plane the extents are principal spreads, which no outline bounds one by one
            outline_hidden=1.0
            if frame is None
            else outline_hidden(seg.mask, points_map, lambda p: frame.coords(p)[:, 2]),
        )
        return attrs, shares, xy

    def support_plane(self, depth_m: np.ndarray, intrinsics: CameraIntrinsics) -> SupportPlane | None:
        """The plane objects stand on in a depth image (the first stage of `ground`), or None.

        Args:
            depth_m: (H, W) float32 depth [m]; 0 or NaN where there is no reading.
            intrinsics: its camera.
        """
        # Only the plane's pixel grid is back-projected (1/16 of the pixels at stride 4): the grid's own
        # camera has the focal lengths and the principal point divided by the stride, so its points are
        # those of the full point map's grid (as `ground` samples them).
        s = self.config.plane_stride_px
        if s == 1:
            return self._support_plane(depth_to_point_map(depth_m, intrinsics))[0]
        K = intrinsics
        h, w = -(-K.height // s), -(-K.width // s)
        grid = CameraIntrinsics(K.fx / s, K.fy / s, K.cx / s, K.cy / s, width=w, height=h)
        Ps = depth_to_point_map(depth_m[::s, ::s], grid).reshape(-1, 3)
        return fit_support_plane(Ps[np.isfinite(Ps[:, 2])], self.config)

    def _support_plane(self, points_map: np.ndarray) -> tuple[SupportPlane | None, np.ndarray]:
        """The plane fitted on every `plane_stride_px`-th point of an (H, W, 3) point map, and the points."""
        stride = self.config.plane_stride_px
        Ps = points_map[::stride, ::stride].reshape(-1, 3)
        Ps = Ps[np.isfinite(Ps[:, 2])]
        return fit_support_plane(Ps, self.config), Ps

    def ground(
        self, rgb: np.ndarray, depth_m: np.ndarray, intrinsics: CameraIntrinsics, prompt: str
    ) -> GroundingResult:
        """Candidates for `prompt` in one RGB-D frame, best first.

        Args:
            rgb: (H, W, 3) uint8 colour image, registered to the depth image.
            depth_m: (H, W) float32 depth along the optical axis [m]; 0 or NaN where there is no reading.
            intrinsics: the camera of both images.
            prompt: what to find ("the red mug", "the largest object", "the can left of the bowl").

        Returns:
            A `GroundingResult` (candidates best first; possibly none when nothing stands out of the scene).
        """
        t0 = time.perf_counter()
        rgb, depth_m, intrinsics, prompt = validate_frame(rgb, depth_m, intrinsics, prompt)
        parsed = parse_prompt(prompt)
        cfg = self.config
        P = depth_to_point_map(depth_m, intrinsics)
        plane, Ps = self._support_plane(P)
        frame = PlaneFrame(plane) if plane is not None else None
        hull = None
        if plane is not None and frame is not None:
            inl = Ps[np.abs(plane.height_m(Ps)) < cfg.ransac_inlier_m]
            hull = cv2.convexHull(frame.coords(inl)[:, :2].astype(np.float32))
        t1 = time.perf_counter()
        focal_px = 0.5 * (intrinsics.fx + intrinsics.fy)
        segs = segment_objects(
            rgb,
            P,
            focal_px,
            plane,
            cfg,
            support_hull=hull,
            plane_coords=frame.coords if frame is not None else None,
        )
        t2 = time.perf_counter()
        described = [self._attributes(rgb, P, s, frame, focal_px) for s in segs]
        t3 = time.perf_counter()
        candidates: tuple[Candidate, ...] = ()
        n_contenders = 0
        if segs:
            totals = self._totals(parsed, described, has_plane=plane is not None)
            scores = score_of_total(totals)
            probs, p_none = match_probabilities(totals, self.confidence)
            n_contenders = contenders(probs, p_none, self.confidence)
            order = np.argsort(-totals, kind="stable")[: cfg.max_candidates]
            candidates = tuple(
                Candidate(segs[i].mask, segs[i].box_xyxy, float(scores[i]), described[i][0], float(probs[i]))
                for i in order
            )
        t4 = time.perf_counter()
        timing = GroundingTiming(t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0)
        log.debug("grounded %r: %d candidates in %.1f ms", prompt, len(candidates), 1e3 * timing.total_s)
        return GroundingResult(
            prompt=prompt, candidates=candidates, support_plane=plane, timing=timing, contenders=n_contenders
        )

    def _description_sim(self, text: str, described: list) -> np.ndarray:
        """(K,) cosine of `text` with each candidate's description."""
        E = self._embed([text, *(d[0].description for d in described)])
        return E[1:] @ E[0]

    def _for_text(self, feats: CandidateFeatures, text: str, described: list) -> CandidateFeatures:
        """`feats` with `description_sim` for another text (the rest does not depend on the text)."""
        return dataclasses.replace(feats, description_sim=self._description_sim(text, described))

    def _features(self, text: str, described: list) -> CandidateFeatures:
        return CandidateFeatures(
            description_sim=self._description_sim(text, described),
            colour_shares=np.array([[d[1][c] for c in PALETTE] for d in described]),
            palette=PALETTE,
            size_classes=tuple(d[0].size_class for d in described),
            families=tuple(d[0].shape_family for d in described),
            alternative_families=tuple(d[0].shape_family_alternative for d in described),
            extents_m=np.stack([d[0].extent_m for d in described]),
            plane_xy_m=np.stack([d[2] for d in described]),
            distance_m=np.array([float(np.linalg.norm(d[0].centroid_cam)) for d in described]),
            top_heights=np.stack([d[0].top_height_histogram for d in described]),
            handles=np.array([d[0].handle_seen for d in described], dtype=bool),
            tapers=np.array([d[0].taper for d in described], dtype=np.float64),
            outline_hidden=np.array([d[0].outline_hidden for d in described], dtype=np.float64),
        )

    def _prior_for(self, parsed: ParsedPrompt, has_plane: bool) -> NounPrior | None:
        if parsed.generic:
            return None
        prior = self.noun_prior(parsed.noun)
        if prior is None or has_plane:
            return prior
        # without a plane the extents are principal spreads, largest first
        t = None if prior.typical_extent_m is None else np.sort(prior.typical_extent_m)[::-1]
        return NounPrior(prior.family, prior.match_score, t)

    def _knowledge_for(self, parsed: ParsedPrompt) -> Any:
        """What the knowledge table knows of the prompt's noun, or None (a generic noun, no near entry)."""
        return None if parsed.generic else self.knowledge.lookup(parsed.noun)

    def _totals(self, parsed: ParsedPrompt, described: list, has_plane: bool = True) -> np.ndarray:
        """(K,) score totals of the described candidates for `parsed` (`score.candidate_totals`)."""
        # every text this prompt needs goes through the encoder in one batch (one forward pass, not four)
        phrases = [p for p in (parsed, parsed.reference) if p is not None]
        self._embed(
            [t for p in phrases for t in (p.text, p.noun) if t]
            + list(FAMILY_TEXTS.values())
            + [d[0].description for d in described]
        )
        feats = self._features(parsed.text, described)
        noun_prior = self._prior_for(parsed, has_plane)
        rivals = self._rivals(parsed, feats, described, noun_prior, has_plane)
        reference = None
        if parsed.reference is not None:
            reference = (
                self._for_text(feats, parsed.reference.text, described),
                self._shape_prob(parsed.reference),
            )
        return candidate_totals(
            parsed,
            feats,
            self._shape_prob(parsed),
            reference,
            self.weights,
            noun_prior=noun_prior,
            reference_prior=None
            if parsed.reference is None
            else self._prior_for(parsed.reference, has_plane),
            rivals=rivals,
            knowledge=self._knowledge_for(parsed),
            reference_knowledge=None if parsed.reference is None else self._knowledge_for(parsed.reference),
        )

    def _rivals(
        self,
        parsed: ParsedPrompt,
        feats: CandidateFeatures,
        described: list,
        noun_prior: NounPrior | None,
        has_plane: bool,
    ) -> RivalReadings | None:
        """The candidates read as the prompt's noun and as the library's other families (`RivalReadings`);
        None when the noun names no family or the rival term is off."""
        if noun_prior is None or self.weights.rival <= 0.0 or not parsed.noun:
            return None
        others = []
        for name in self._family_names():
            rival = ParsedPrompt(text=name, noun=name)
            prior = self._prior_for(rival, has_plane)
            if prior is not None and prior.family != noun_prior.family:
                others.append((self._for_text(feats, name, described), self._shape_prob(rival), prior))
        return RivalReadings(self._for_text(feats, parsed.noun, described), tuple(others))

    def _family_names(self) -> tuple[str, ...]:
        """The prior library's family names (none for a library that does not list them)."""
        return tuple(getattr(self.priors, "families", ()))


_GROUNDERS: dict[GroundingConfig, Grounder] = {}
_GROUNDERS_LOCK = threading.Lock()


def ground(
    rgb: np.ndarray,
    depth_m: np.ndarray,
    intrinsics: CameraIntrinsics,
    prompt: str,
    config: GroundingConfig | None = None,
) -> GroundingResult:
    """Ground `prompt` with the embedded default; one shared `Grounder` per config (see `Grounder.ground`)."""
    cfg = config or GroundingConfig()
    if not isinstance(cfg, GroundingConfig):
        raise InvalidInputError(f"config must be a GroundingConfig, got {type(cfg).__name__}")
    with _GROUNDERS_LOCK:
        grounder = _GROUNDERS.get(cfg)
        if grounder is None:
            grounder = _GROUNDERS[cfg] = Grounder(cfg)
    return grounder.ground(rgb, depth_m, intrinsics, prompt)
