"""Scoring candidates against a parsed prompt.

Every candidate gets a total that is a weighted sum of terms, each in [-1, 1] (semantic similarity is a
cosine):

| term | value | weight |
|---|---|---|
| semantic | cosine (MiniLM) of the prompt's target phrase and the candidate's description | 1.0 |
| colour | +1 when >= 40 % of the mask has an asked colour, falling linearly to -1 at 0 % | 1.5 |
| shape | fit of the measured shape family to the noun: p(family | noun) / max p, to [-1, 1] | 0.5 |
| size, superlative | rank among the plausible candidates: +1 the extreme, -1 the other end | 2.0 |
| size, adjective | "small" +1 for size class small, 0 medium, -1 large (and mirrored for "large") | 0.5 |
| position | rank among the plausible candidates ("nearest", "leftmost", ...), like superlatives | 1.5 |
| relation | direction cosine to the reference object ("left of", "behind") or nearness ("next to") | 1.5 |

The colour weight is the largest single-term weight because a colour word is the most reliable thing a
prompt says about an image. Ranking terms (superlatives, positions) only rank the *plausible* candidates:
those whose semantic + colour + shape total is within 0.6 of the best (so "the largest red object" ranks
the red ones). p(family | noun) is a softmax (temperature 0.05) over the MiniLM similarities of the noun
with one sentence per shape family (`FAMILY_TEXTS`); generic nouns ("object", "thing") and the family
"irregular" give 0. Relations are measured on the support plane as the camera sees it: "left of" is along
the image's left, "behind" is farther from the camera along the plane, "in front of" nearer; the reference
is the best candidate for the reference phrase (same scoring without positions) and gets -1 itself.

The returned score is sigmoid(2 (total - 1)): in (0, 1), monotone in the total, comparable within a prompt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prompose_grasp.perception.grounding.language import ParsedPrompt

__all__ = ["FAMILY_TEXTS", "CandidateFeatures", "ScoringWeights", "score_candidates"]

#: One sentence per measured shape family; the noun's similarity to them gives p(family | noun).
FAMILY_TEXTS: dict[str, str] = {
    "box": "a box-shaped object such as a carton, a package, a book or a cereal box",
    "cylinder": "a cylindrical object such as a can, a bottle, a mug, a cup, a jar or a glass",
    "sphere": "a round ball-shaped object such as a ball, an orange or an apple",
    "flat": "a flat object such as a plate, a tray, a board or a closed laptop",
    "elongated": "a long thin object such as a tube, a pen, a stick, a tool or a banana",
}


@dataclass(frozen=True)
class ScoringWeights:
    """Weights of the score terms (module docstring)."""

    semantic: float = 1.0
    colour: float = 1.5
    shape: float = 0.5
    size_superlative: float = 2.0
    size_adjective: float = 0.5
    position: float = 1.5
    relation: float = 1.5
    plausible_margin: float = 0.6
    colour_full_share: float = 0.4
    family_temperature: float = 0.05


@dataclass(frozen=True)
class CandidateFeatures:
    """What scoring needs of each of K candidates (arrays over candidates).

    Attributes:
        description_sim: (K,) cosine of the target phrase with each description (filled by the caller).
        colour_shares: (K, len(PALETTE)) share of each palette colour in each mask; `palette` names columns.
        size_classes: K size class names.
        families: K shape family names.
        extents_m: (K, 3) footprint length, width, height [m].
        plane_xy_m: (K, 2) (right, forward) footprint centres on the support plane [m] (camera x, z without
            a plane).
        distance_m: (K,) distance of the centroids from the camera [m].
    """

    description_sim: np.ndarray
    colour_shares: np.ndarray
    palette: tuple[str, ...]
    size_classes: tuple[str, ...]
    families: tuple[str, ...]
    extents_m: np.ndarray
    plane_xy_m: np.ndarray
    distance_m: np.ndarray


def _rank_term(values: np.ndarray, direction: int, plausible: np.ndarray) -> np.ndarray:
    """+1 for the extreme (direction +1: largest value) plausible candidate, linearly to -1; others -1."""
    out = np.full(len(values), -1.0)
    idx = np.flatnonzero(plausible)
    if len(idx) == 1:
        out[idx] = 1.0
    elif len(idx) > 1:
        order = idx[np.argsort(-direction * values[idx], kind="stable")]
        out[order] = 1.0 - 2.0 * np.arange(len(order)) / (len(order) - 1)
    return out


def _base_terms(
    parsed: ParsedPrompt, feats: CandidateFeatures, shape_prob: dict[str, float] | None, w: ScoringWeights
) -> np.ndarray:
    """Semantic + colour + shape + size-adjective total of each candidate."""
    total = w.semantic * feats.description_sim.astype(np.float64)
    if parsed.colours:
        cols = [feats.palette.index(c) for c in parsed.colours]
        share = feats.colour_shares[:, cols].max(axis=1)
        total += w.colour * (2.0 * np.clip(share / w.colour_full_share, 0.0, 1.0) - 1.0)
    if shape_prob:
        pmax = max(shape_prob.values())
        total += w.shape * np.array(
            [0.0 if f not in shape_prob else 2.0 * shape_prob[f] / pmax - 1.0 for f in feats.families]
        )
    if parsed.size is not None and not parsed.size[2]:
        classes = ("small", "medium", "large")
        value = np.array([classes.index(c) - 1.0 for c in feats.size_classes])  # -1, 0, +1
        total += w.size_adjective * parsed.size[1] * value
    return total


def _measure(feats: CandidateFeatures, measure: str) -> np.ndarray:
    e = feats.extents_m
    if measure == "volume":
        return e[:, 0] * e[:, 1] * e[:, 2]
    if measure == "height":
        return e[:, 2]
    return e.max(axis=1)  # length


def score_candidates(
    parsed: ParsedPrompt,
    feats: CandidateFeatures,
    shape_prob: dict[str, float] | None,
    reference: tuple[CandidateFeatures, dict[str, float] | None] | None = None,
    weights: ScoringWeights | None = None,
) -> np.ndarray:
    """(K,) float64 scores in (0, 1) of the candidates for `parsed` (higher is better).

    Args:
        parsed: the parsed prompt.
        feats: candidate features with `description_sim` for `parsed.text`.
        shape_prob: p(family | noun) for `parsed.noun`, or None for a generic noun.
        reference: for a relation, the same features with `description_sim` for the reference phrase, and
            p(family | reference noun).
        weights: term weights.
    """
    w = weights or ScoringWeights()
    K = len(feats.description_sim)
    if K == 0:
        return np.zeros(0)
    base = _base_terms(parsed, feats, shape_prob, w)
    plausible = base >= base.max() - w.plausible_margin
    total = base.copy()
    if parsed.size is not None and parsed.size[2]:
        measure, direction, _ = parsed.size
        total += w.size_superlative * _rank_term(_measure(feats, measure), direction, plausible)
    if parsed.position is not None:
        if parsed.position in ("leftmost", "rightmost"):
            values, direction = feats.plane_xy_m[:, 0], (-1 if parsed.position == "leftmost" else 1)
        else:
            values, direction = feats.distance_m, (-1 if parsed.position == "nearest" else 1)
        total += w.position * _rank_term(values, direction, plausible)
    if parsed.relation is not None and parsed.reference is not None and reference is not None:
        ref_feats, ref_shape = reference
        ref_base = _base_terms(parsed.reference, ref_feats, ref_shape, w)
        ref = int(np.argmax(ref_base))
        delta = feats.plane_xy_m - feats.plane_xy_m[ref]
        dist = np.linalg.norm(delta, axis=1)
        safe = np.maximum(dist, 1e-9)
        axis = {
            "left_of": np.array([-1.0, 0.0]),
            "right_of": np.array([1.0, 0.0]),
            "behind": np.array([0.0, 1.0]),
            "in_front_of": np.array([0.0, -1.0]),
        }.get(parsed.relation)
        if axis is None:  # "near": +1 touching, -1 at 30 cm or more
            term = 1.0 - 2.0 * np.clip(dist / 0.3, 0.0, 1.0)
        else:
            # direction cosine, faded out for candidates within 3 cm (no direction to speak of)
            term = (delta @ axis) / safe * np.clip(dist / 0.03, 0.0, 1.0)
        term[ref] = -1.0
        total += w.relation * term
    return 1.0 / (1.0 + np.exp(-2.0 * (total - 1.0)))
