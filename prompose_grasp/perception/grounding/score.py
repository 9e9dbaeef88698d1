"""Scoring candidates against a parsed prompt.

Every candidate gets a total that is a weighted sum of terms, each in [-1, 1] (semantic similarity is a
cosine):

| term | value | weight |
|---|---|---|
| semantic | cosine (MiniLM) of the prompt's target phrase and the candidate's description | 1.0 |
| colour | +1 when >= 40 % of the mask has an asked colour, falling linearly to -1 at 0 % | 1.5 |
| shape | fit of the measured shape family to the noun: p(family | noun) / max p, to [-1, 1] (*) (***) | 0.5 |
| metric size | log-normal fit of the measured extents to the typical size of the noun's prior family | 1.5 |
| top heights | overlap of the candidate's and the family mesh's top-height histograms, to [-1, 1] | 1.5 |
| handle | a handle seen: +1 when the noun's family mesh (or entry) has one, -1 when it has none | 1.0 |
| taper | a round candidate's taper unlike the noun's family mesh's: to -1; 0 alike or unmeasured | 1.0 |
| rival | another library family explains the candidate better than the noun's: minus the difference | 0.5 |
| knowledge size | the measured extents against the named object's typical size range (**) | 1.5 |
| knowledge colour | share of the named object's typical colours (prompt without a colour) (**) | 0.75 |
| knowledge shape | measured shape family against the named object's coarse shape (**) | 0.5 |
| size, superlative | rank among the plausible candidates: +1 the extreme, -1 the other end | 2.0 |
| size, adjective | "small" +1 for size class small, 0 medium, -1 large (and mirrored for "large") | 0.5 |
| position | rank among the plausible candidates ("nearest", "leftmost", ...), like superlatives | 1.5 |
| relation | direction cosine to the reference object ("left of", "behind") or nearness ("next to") | 1.5 |

(*) A box/cylinder reading near its threshold (`describe.shape_families`): the mean of both readings' fits.
(**) Times the weight of the knowledge table's match for the noun (`knowledge.KnowledgeMatch.weight`: 1 for
a name or synonym of the table, less for the nearest entries of an unseen name, no term without a match).
(***) For a noun the library has no family for and the table knows: the entry's coarse shape (below).

The colour weight is the largest single-term weight because a colour word is the most reliable thing a
prompt says about an image. Ranking terms (superlatives, positions) only rank the *plausible* candidates:
those whose semantic + colour + shape total is within 0.6 of the best (so "the largest red object" ranks
the red ones). p(family | noun) is a softmax (temperature 0.05) over the MiniLM similarities of the noun
with one sentence per shape family (`FAMILY_TEXTS`); generic nouns ("object", "thing") and the family
"irregular" give 0. Relations are measured on the support plane as the camera sees it: "left of" is along
the image's left, "behind" is farther from the camera along the plane, "in front of" nearer; the reference
is the best candidate for the reference phrase (same scoring without positions) and gets -1 itself.

Metric size. When the noun names a family of the prior library (`NounPrior`: "mug" -> the mug family, typical
size 11.6 x 8.2 cm footprint, 9.5 cm tall), each candidate's measured extents e = (footprint length, width,
height) are compared with the family's typical extents t in log space, r = log(e / t), per axis. Objects of a
category vary by about +-30 % and the visible extents only shrink under occlusion and self-occlusion (the far
half of a round object is not seen), so "too large" (r > 0) is judged with sigma 0.35 on every axis, "too
small" with sigma 0.45 (footprint length), 0.8 (footprint width: a cylinder shows half its depth) and 0.35
(height: amodal, objects stand on the plane). The term is 2 exp(-d2 / 2) - 1 with d2 the mean of (r / sigma)^2
over the three axes: +1 at the typical size, 0 at about 1.2 sigma, -1 far off. It is left out when the prompt
has a size word ("the small mug": the user then says the size is not typical).
Measured on 60 generated scenes (seed 5, 498 category prompts, `python -m
prompose_grasp.perception.grounding.bench`): top-1 from 51.8 % to 78.3 %; weights 1.0 / 2.0 gave 73.9 / 80.1 %
but a heavier size term starts to overrule colour words, so 1.5.

Top heights. The same family's mean mesh (`ShapePrior.points` at the typical size, +y up) gives a top-height
histogram (`describe.top_height_histogram`); the term is 2 sum_i min(p_i, q_i) - 1 with the candidate's p:
+1 for identical histograms, -1 for disjoint ones. It tells a laptop (low base, thin screen) from a carton,
a bottle (shoulder below the neck) from a can, a camera (hump over the body) from a mug. Measured like the
size term on the 60 scenes: 78.3 % -> 85.9 % (test split 83.0 % -> 95.5 %); weights 1.0 / 2.0 gave
84.9 / 86.9 %; 1.5 leaves room for colour words. A per-height footprint-length profile (bottle neck, mug
handle) helped mugs (62 -> 75 %) but hurt laptops (96 -> 88 %) and sacks, net -1.4 %, and was dropped.

Handle. A mug and a cup have the same size, shape family and top heights; a mug's handle is what tells them
apart, when the camera sees it (`describe.handle_seen`). The noun's family mesh has a handle when the same
test finds one on its points seen all around (in the default library: the mug family only). A candidate
showing a handle gains for "the mug" and loses for "the cup", "the can", "the bowl"; one showing none is
not judged (the handle may be behind the body). This fixes the mug that outscored the cups for "the cup"
once its handle stayed in its mask (docs/grounding.md, "Mug handles"). For a noun the library has no family
for, the knowledge table's entry says it instead (`knowledge_handle_sign`, times the match's weight): a
handle seen gains for an entry with feature "handle" whose body can be round (a kettle, a pitcher) and
loses for a plain round body (coarse shape cylinder or round, no handle: an apple, an orange); an
irregular kind without one is not judged (a toy's arm or a duck's beak beside a round body reads like a
handle), nor a long or flat one (a hammer's or a knife's handle is its grip, not a loop beside a body).

Taper. A hidden-handle mug and a paper cup still look alike; what tells them apart is that the cup widens
upwards (`describe.taper`: log of the upper band's radius over the lower's; development table: mugs -0.02 to
0.03, cups 0.05 to 0.21, round-looking cameras -0.48 to -0.03). The term compares a round candidate's taper
t_c with that of the noun's family mesh t_n (measured the same way, when the mesh reads round: cup 0.17,
bowl 0.16, mug and can 0, jar -0.08): exp(-((t_c - t_n) / 0.08)^2 / 2) - 1. 0 alike, -0.05 for a mug's 0.025
against a mug's 0, -0.18 for the least tapered cup's 0.05, -0.85 for a typical cup's 0.16. Sigma 0.08, not
the mugs' spread (0.02): a real mug may taper by 5-10 % of its radius (-0.39 at 0.08). It only takes away:
standing straight does not make a candidate a mug (a can does), and a term that added for it lifted every
straight thing over the hidden-handle mugs' scores. Nouns whose mesh narrows upwards by more than 0.1
(bottle -0.27: its shoulder; camera -0.30: its hump) are not judged: where the narrowing falls varies (the
generated bottles read -0.45 to -0.12). Unmeasured (not round, or a band hidden) gives 0.

Rival families. A candidate can fit the noun well and another kind of object better: a cup or a soda can for
"the mug", a carton for "the sack". When the noun names a family of the prior library, each candidate is also
scored, by the same semantic, shape, metric size, top-height, handle and taper terms, as every other family
of the library, with the family's name in place of the noun and the noun alone on the own side (so the
prompt's other words count the same on both sides; the family names are embedded once, at warm-up). When
the best other family's total exceeds the noun's, the difference times the weight is taken from the
candidate (`RivalReadings`). Only a candidate that another family explains better loses, and only a noun of
the library is judged: a user's word the library does not know gives no term. Measured on the grounding
benchmark's development set (15 scenes of dev split 22): category prompts 94.6 -> 97.8 % top-1 (sacks 40 ->
85 %: the cartons they lost to are read better as cartons), colour + category prompts and the test split
unchanged; docs/grounding.md, "Rival families".

Object knowledge. The knowledge table (`perception.knowledge`, docs/knowledge.md) knows what a named object
usually is: "tuna can" 8-9 cm across and 3.3-4.5 cm tall, "mustard bottle" yellow, "banana" long and thin.
Its match for the prompt's noun scores three things. Size: the candidate's extents and the entry's ranges
are both sorted largest first (the table's ranges do not say which way the object stands), and an extent
outside its range by the log ratio r (with 1 cm of slack for segmentation and noise) adds (r / sigma)^2:
sigma 0.2 above the range (what a view shows only exceeds the object when segmentation took in a
neighbour), 0.35 / 0.6 / 0.6 below it (occlusion and the half of a round body the camera does not see
only shrink what is measured). The term is 2 exp(-d2 / 2) - 1 with d2 the sum over the axes: the ranges
already span the kind's variation, so one extent outside them counts. A height seen in full is judged
strictly for being too small (sigma 0.15 in place of the lenient one): when free space bounds the
candidate's outline all round (`describe.outline_hidden` under 0.05, the lenient sigma back by 0.25),
nothing in front hides its top and the plane under it is known, so a 21 cm cracker box is no 25-34 cm
cereal box and a 9 cm tomato-paste can no 12 cm soda can. Its footprint is never judged so: a round body's
far half is not seen, and thin parts near the table (wings, blades) fall under the segmentation's height
cut with nothing in front of them. For a kind that rests on its long
side and does not stand on its end (knowledge feature "lies": a banana, a knife, a pen), the measured height
is judged against the shortest range and the footprint against the other two: a yellow bottle standing 19
cm tall is as long as a banana, but no banana stands on its end. Colour: the share of the entry's
typical colours in the mask, +1 from 50 % (a label rarely covers less) down to -0.3 at none (a kind's
typical colour is usual, not certain: a blue bowl is still a bowl); only when the prompt names no colour,
since a colour word is the user's own. Shape: the coarse shape's fit to the measured
family. When the table names the noun more closely than the prior library does (its match's similarity
above the library's, and a weight of at least 0.5: "sugar box" is an entry, the library only has boxes),
its size range and coarse shape replace the family's typical size and shape: the metric size term, the
family's shape term and the rival families' term are left out (a tuna can is a short cylinder that reads
flat, and the can family's shape had preferred a slim marker to it); for a family's own name ("bowl") all
count. Where both name the noun exactly and it is not the family's own name ("cereal box" and "soda can"
are aliases of the box and can families and entries of the table), the entry's range is that product's
size and the family's typical extents every box's or can's (`Grounder.noun_prior`): a family that rests
on any face (the box, 15 x 7 x 20 cm standing) has no typical size left and the metric size term is left
out; a round family stands on its base, so the entry's two most alike extents become its footprint and
the third its height (a soda can 6.6 x 6.6 cm under 12.2 cm, the can family's 11.5 cm no more). When the
library has no family for the noun and the table has an entry (weight at least 0.5:
"stapler", "elephant", "eyeglasses"), the shape term reads the entry's coarse shape in place of the noun's
similarity to the family sentences: those sentences guess a shape from how the word reads ("elephant" lands
nearest "a long thin object", "eyeglasses" nearest "a cylindrical object"), which for a word they were not
written for is noise that had decided picks between look-alike sizes.

The returned score is sigmoid(2 (total - 1)): in (0, 1), monotone in the total, comparable within a prompt.
The totals themselves (`candidate_totals`) give the calibrated match probabilities (`confidence`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.perception.grounding.language import ParsedPrompt

__all__ = [
    "FAMILY_TEXTS",
    "SAME_MATCH",
    "SHAPE_FIT",
    "CandidateFeatures",
    "NounPrior",
    "RivalReadings",
    "ScoringWeights",
    "candidate_totals",
    "coarse_shape_fits",
    "height_seen_in_full",
    "knowledge_handle_sign",
    "knowledge_size_term",
    "knowledge_terms",
    "knows_more_than_family",
    "metric_size_term",
    "score_candidates",
    "score_of_total",
    "total_of_score",
]

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
    """Weights of the score terms (module docstring); the `size_*_sigma` are log-normal widths, `taper_sigma`
    the taper term's width, `taper_judged_from` the least taper of a noun's mesh that the term judges."""

    semantic: float = 1.0
    colour: float = 1.5
    shape: float = 0.5
    metric_size: float = 1.5
    top_heights: float = 1.5
    handle: float = 1.0
    taper: float = 1.0
    rival: float = 0.5
    knowledge_size: float = 1.5
    knowledge_colour: float = 0.75
    knowledge_shape: float = 0.5
    knowledge_over_sigma: float = 0.2
    knowledge_under_sigma: tuple[float, float, float] = (0.35, 0.6, 0.6)
    knowledge_under_sigma_seen: float = 0.15
    knowledge_outline_free: float = 0.05
    knowledge_outline_hidden: float = 0.25
    knowledge_slack_m: float = 0.01
    knowledge_colour_full_share: float = 0.5
    knowledge_colour_miss: float = 0.3
    knowledge_replaces_family_size: float = 0.5
    taper_sigma: float = 0.08
    taper_judged_from: float = -0.1
    size_over_sigma: float = 0.35
    size_under_sigma: tuple[float, float, float] = (0.45, 0.8, 0.35)
    size_superlative: float = 2.0
    size_adjective: float = 0.5
    position: float = 1.5
    relation: float = 1.5
    plausible_margin: float = 0.6
    colour_full_share: float = 0.4
    family_temperature: float = 0.05


@dataclass(frozen=True)
class NounPrior:
    """What the prior library knows about a prompt's noun.

    Attributes:
        family: the library family the noun matched ("mug").
        match_score: its retrieval score (cosine, >= the library's threshold).
        typical_extent_m: (3,) float64 [m] the family's typical extents in the order the candidates are
            measured: footprint length >= footprint width, height (sorted descending without a plane); a
            product's, for a product the table names (`Grounder.noun_prior`); None when there is none to
            judge (a product of a family that rests on any face: the table's range alone).
        top_height_histogram: (HEIGHT_BINS,) shares of the family's mean mesh (`describe`), or None.
        has_handle: the family's mean mesh has a handle (`describe.handle_seen` on its points).
        taper: the family's mean mesh's `describe.taper` (NaN when the mesh does not read round).
    """

    family: str
    match_score: float
    typical_extent_m: np.ndarray | None
    top_height_histogram: np.ndarray | None = None
    has_handle: bool = False
    taper: float = float("nan")


#: How well a measured shape family (`describe.SHAPE_FAMILIES`, columns) fits a knowledge entry's coarse shape
#: (`knowledge.COARSE_SHAPES`, rows), in [-1, 1]. What a view can make of each shape sets the values: a round
#: thing's footprint can read box-like from one side, a short can reads flat, a lying bottle elongated, a
#: flat box reads box or flat; "irregular" (toys, tools with heads) says nothing either way.
_FIT_COLUMNS = ("box", "cylinder", "sphere", "flat", "elongated", "irregular")
SHAPE_FIT: dict[str, dict[str, float]] = {
    shape: dict(zip(_FIT_COLUMNS, row))
    for shape, row in (
        #             box  cylinder sphere flat elongated irregular
        ("box",       (1.0, -0.5, -1.0, 0.5, 0.0, 0.0)),
        ("cylinder",  (-0.5, 1.0, 0.0, 0.0, 0.0, 0.0)),
        ("round",     (-1.0, 0.3, 1.0, -0.5, -1.0, 0.3)),
        ("flat",      (0.3, -0.3, -1.0, 1.0, 0.0, 0.0)),
        ("elongated", (0.0, 0.0, -1.0, 0.0, 1.0, 0.0)),
        ("irregular", (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
    )
}  # fmt: skip


#: A candidate is long and thin when its largest extent is this many times the next (`describe`'s rule 1 for
#: a footprint, here orientation-free).
ELONGATED_RATIO = 2.5


def _long_thin(extents_m: np.ndarray) -> np.ndarray:
    """(K,) bool: the largest of each candidate's (K, 3) extents is `ELONGATED_RATIO` times the next."""
    e = np.sort(np.asarray(extents_m, dtype=np.float64), axis=1)[:, ::-1]
    return e[:, 0] >= ELONGATED_RATIO * e[:, 1]


def height_seen_in_full(feats: CandidateFeatures, w: ScoringWeights) -> np.ndarray | None:
    """(K,) in [0, 1]: how surely each candidate's measured height is its whole height (module docstring,
    "Object knowledge"); None when the outlines were not judged.

    With free space all round (`describe.outline_hidden` at most `knowledge_outline_free`, falling to
    nothing at `knowledge_outline_hidden`) the top is seen and the plane is known. The footprint is never
    sure, even then: a round body's far half is behind it, and thin parts near the table (a toy plane's
    wings, a knife's blade) fall under the segmentation's height cut with nothing in front of them.
    """
    if feats.outline_hidden is None:
        return None
    h = np.asarray(feats.outline_hidden, dtype=np.float64)
    free, hidden = w.knowledge_outline_free, w.knowledge_outline_hidden
    return np.clip((hidden - h) / (hidden - free), 0.0, 1.0)


def knowledge_size_term(
    extents_m: np.ndarray,
    lo_m: np.ndarray,
    hi_m: np.ndarray,
    w: ScoringWeights,
    lies: bool = False,
    height_seen: np.ndarray | None = None,
) -> np.ndarray:
    """(K,) in [-1, 1]: how well (K, 3) measured extents [m] (footprint length, width, height) fall in an
    object's typical (3,) size range [lo, hi] (both largest first): orientation-free, or, for a kind that
    `lies` on its long side, with the height against the shortest range (module docstring, "Object
    knowledge"). `height_seen`: (K,) in [0, 1], how surely the view shows each measured height in full
    (`height_seen_in_full`); None: none is sure."""
    e = np.maximum(np.asarray(extents_m, dtype=np.float64), 1e-3)
    if lies:
        # footprint largest first, then the height: a 19 cm bottle standing is no banana lying
        footprint = np.argsort(-e[:, :2], axis=1, kind="stable")
        order = np.column_stack([footprint, np.full(len(e), 2)])
    else:
        order = np.argsort(-e, axis=1, kind="stable")
    e = np.take_along_axis(e, order, axis=1)
    over = np.log(np.maximum(e - w.knowledge_slack_m, 1e-3) / hi_m)
    under = np.log((e + w.knowledge_slack_m) / lo_m)
    r_over, r_under = np.maximum(over, 0.0), np.minimum(under, 0.0)
    under_sigma = np.broadcast_to(np.asarray(w.knowledge_under_sigma, dtype=np.float64), e.shape)
    if height_seen is not None:
        # a height seen in full is the object's own: too small is judged strictly
        sure = np.where(order == 2, np.asarray(height_seen, dtype=np.float64)[:, None], 0.0)
        under_sigma = under_sigma + (w.knowledge_under_sigma_seen - under_sigma) * sure
    # summed, not averaged, over the axes: the range already spans the kind's variation, so one extent
    # outside it is as telling as three
    d2 = np.sum((r_over / w.knowledge_over_sigma) ** 2 + (r_under / under_sigma) ** 2, axis=1)
    return 2.0 * np.exp(-0.5 * d2) - 1.0


def knowledge_terms(
    parsed: ParsedPrompt, feats: CandidateFeatures, match: Any, w: ScoringWeights
) -> np.ndarray:
    """(K,) the object-knowledge total of each candidate for a `knowledge.KnowledgeMatch` (module docstring):
    size range, typical colours (when the prompt names none) and coarse shape, times the match's weight."""
    total = np.zeros(len(feats.description_sim))
    if parsed.size is None:
        lo, hi = match.size_lo_m, match.size_hi_m
        total += w.knowledge_size * knowledge_size_term(
            feats.extents_m, lo, hi, w, match.lies, height_seen_in_full(feats, w)
        )
    if match.colours and not parsed.colours:
        cols = [feats.palette.index(c) for c in match.colours]
        share = feats.colour_shares[:, cols].sum(axis=1)
        # typical colours are what a kind usually shows, not what it must: a match adds up to 1, a miss
        # takes at most `knowledge_colour_miss` (a blue bowl is still a bowl)
        full = np.clip(share / w.knowledge_colour_full_share, 0.0, 1.0)
        total += w.knowledge_colour * ((1.0 + w.knowledge_colour_miss) * full - w.knowledge_colour_miss)
    total += w.knowledge_shape * coarse_shape_fits(match, feats)
    return match.weight * total


def knowledge_handle_sign(match: Any) -> float:
    """+1 when a handle seen on a candidate speaks for a `knowledge.KnowledgeMatch`, -1 when it speaks
    against it, 0 when a view cannot say (module docstring, "Handle"). `describe.handle_seen` finds a loop
    or grip beside a round body: it speaks for an entry with feature "handle" whose body can be round (coarse
    shape cylinder, round or irregular: a kettle, a pitcher), against one that is every way a plain round
    body (cylinder or round, no handle: an apple, a can); a long or flat kind's "handle" is its grip (a
    knife's, a hammer's), which does not stand beside a round body."""
    bodies = ("cylinder", "round")
    if any("handle" in e.features and e.shape in (*bodies, "irregular") for e in match.entries):
        return 1.0
    if all(e.shape in bodies and "handle" not in e.features for e in match.entries):
        return -1.0
    return 0.0


def coarse_shape_fits(match: Any, feats: CandidateFeatures) -> np.ndarray:
    """(K,) in [-1, 1]: each candidate's measured shape family against the coarse shapes of a
    `knowledge.KnowledgeMatch` (`SHAPE_FIT`, the best of its shapes)."""
    fits = np.array([max(SHAPE_FIT[s][f] for s in match.shapes) for f in feats.families])
    if "elongated" in match.shapes:
        # a long thin kind stands as well as it lies (a flashlight, a toothpaste tube on its cap): its
        # extents tell it whatever the family its footprint reads (a standing one reads cylindrical)
        fits = np.where(_long_thin(feats.extents_m), 1.0, fits)
    return fits


def metric_size_term(extents_m: np.ndarray, typical_extent_m: np.ndarray, w: ScoringWeights) -> np.ndarray:
    """(K,) in [-1, 1]: log-normal fit of (K, 3) measured extents [m] to (3,) typical ones (module doc)."""
    r = np.log(np.maximum(np.asarray(extents_m, dtype=np.float64), 1e-3) / np.asarray(typical_extent_m))
    sigma = np.where(r > 0.0, w.size_over_sigma, np.asarray(w.size_under_sigma, dtype=np.float64))
    d2 = np.mean((r / sigma) ** 2, axis=1)
    return 2.0 * np.exp(-0.5 * d2) - 1.0


@dataclass(frozen=True)
class CandidateFeatures:
    """What scoring needs of each of K candidates (arrays over candidates).

    Attributes:
        description_sim: (K,) cosine of the target phrase with each description (filled by the caller).
        colour_shares: (K, len(PALETTE)) share of each palette colour in each mask; `palette` names columns.
        size_classes: K size class names.
        families: K shape family names.
        extents_m: (K, 3) footprint length, width, height [m].
        top_heights: (K, HEIGHT_BINS) top-height histograms (rows sum to 1), or None when not measured.
        handles: (K,) bool, a handle seen on each candidate, or None when not measured.
        tapers: (K,) `describe.taper` of each candidate (NaN where not measured), or None.
        alternative_families: K alternative shape families (None where the family is clear), or None
            (`describe.shape_families`).
        plane_xy_m: (K, 2) (right, forward) footprint centres on the support plane [m] (camera x, z without
            a plane).
        distance_m: (K,) distance of the centroids from the camera [m].
        outline_hidden: (K,) `describe.outline_hidden` of each candidate (0: seen whole), or None.
    """

    description_sim: np.ndarray
    colour_shares: np.ndarray
    palette: tuple[str, ...]
    size_classes: tuple[str, ...]
    families: tuple[str, ...]
    extents_m: np.ndarray
    plane_xy_m: np.ndarray
    distance_m: np.ndarray
    top_heights: np.ndarray | None = None
    handles: np.ndarray | None = None
    tapers: np.ndarray | None = None
    alternative_families: tuple[str | None, ...] | None = None
    outline_hidden: np.ndarray | None = None


@dataclass(frozen=True)
class RivalReadings:
    """The candidates as the prompt's noun and as each other family of the prior library (the rival term).

    Attributes:
        own: the candidates' features with `description_sim` for the prompt's noun alone ("mug").
        others: per other family, the features with `description_sim` for its name ("cup"), p(family | that
            name) and its `NounPrior`.
    """

    own: CandidateFeatures
    others: Sequence[tuple[CandidateFeatures, dict[str, float] | None, NounPrior]]


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


#: Two cosines of one text's embeddings closer than this are the same match: a family's own name ("can")
#: matches its family and its table entry at 1 up to float32 rounding (1 - 5e-8 against 1.0).
SAME_MATCH = 1e-6


def knows_more_than_family(knowledge: Any, noun_prior: NounPrior | None, w: ScoringWeights) -> bool:
    """True when the knowledge table names the prompt's object more closely than the prior library's family
    does (a product, "sugar box", against the box family), or names it where the library has no family for
    it ("stapler", "elephant"): its size range and coarse shape then stand for the family's typical size and
    for the shape read from the noun's words."""
    if knowledge is None or knowledge.weight < w.knowledge_replaces_family_size:
        return False
    return noun_prior is None or knowledge.similarity > noun_prior.match_score + SAME_MATCH


def _base_terms(
    parsed: ParsedPrompt,
    feats: CandidateFeatures,
    shape_prob: dict[str, float] | None,
    w: ScoringWeights,
    noun_prior: NounPrior | None = None,
    knowledge: Any = None,
) -> np.ndarray:
    """Semantic + colour + shape + metric size + object knowledge + size-adjective total of each candidate."""
    total = w.semantic * feats.description_sim.astype(np.float64)
    if parsed.colours:
        cols = [feats.palette.index(c) for c in parsed.colours]
        share = feats.colour_shares[:, cols].max(axis=1)
        total += w.colour * (2.0 * np.clip(share / w.colour_full_share, 0.0, 1.0) - 1.0)
    # a family's typical size and shape are a coarser guess than the entry of a product the table names more
    # closely than the library does ("tuna can", a short cylinder, against the can family): they give way
    knows_better = knows_more_than_family(knowledge, noun_prior, w)
    if shape_prob and not knows_better:
        pmax = max(shape_prob.values())

        def fit(f: str) -> float:
            return 0.0 if f not in shape_prob else 2.0 * shape_prob[f] / pmax - 1.0

        alternatives = feats.alternative_families or (None,) * len(feats.families)
        # near the box/cylinder threshold both readings count half (module docstring)
        fits = np.array(
            [fit(f) if g is None else 0.5 * (fit(f) + fit(g)) for f, g in zip(feats.families, alternatives)]
        )
        # the family reads the footprint: a long thin thing standing up reads cylindrical, and is long and
        # thin all the same
        total += w.shape * np.where(_long_thin(feats.extents_m), np.maximum(fits, fit("elongated")), fits)
    elif knows_better and noun_prior is None:
        # the library has no family for the noun: what its words read like ("elephant" near "a long thin
        # object", "eyeglasses" near "a cylindrical object") is a guess, the table's coarse shape is known
        total += w.shape * knowledge.weight * coarse_shape_fits(knowledge, feats)
    if knowledge is not None:
        total += knowledge_terms(parsed, feats, knowledge, w)
    if (
        noun_prior is not None
        and noun_prior.typical_extent_m is not None
        and parsed.size is None
        and not knows_better
    ):
        total += w.metric_size * metric_size_term(feats.extents_m, noun_prior.typical_extent_m, w)
    if (
        noun_prior is not None
        and noun_prior.top_height_histogram is not None
        and feats.top_heights is not None
    ):
        overlap = np.minimum(feats.top_heights, noun_prior.top_height_histogram[None, :]).sum(axis=1)
        total += w.top_heights * (2.0 * overlap - 1.0)
    if noun_prior is not None and feats.handles is not None:
        total += w.handle * np.where(feats.handles, 1.0 if noun_prior.has_handle else -1.0, 0.0)
    elif knows_better and feats.handles is not None:  # no family for the noun: the table's entry says
        total += w.handle * knowledge.weight * np.where(feats.handles, knowledge_handle_sign(knowledge), 0.0)
    # a noun whose mesh is not round has a NaN taper, which compares False: no term
    if noun_prior is not None and noun_prior.taper >= w.taper_judged_from and feats.tapers is not None:
        gap = np.nan_to_num(feats.tapers - noun_prior.taper)  # NaN: not measured, gap 0, term 0
        total += w.taper * (np.exp(-0.5 * (gap / w.taper_sigma) ** 2) - 1.0)
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


def score_of_total(total: np.ndarray | float) -> np.ndarray:
    """The score in (0, 1) of a score total: sigmoid(2 (total - 1)) (module docstring)."""
    return 1.0 / (1.0 + np.exp(-2.0 * (np.asarray(total, dtype=np.float64) - 1.0)))


def total_of_score(score: np.ndarray | float) -> np.ndarray:
    """The score total of a score, the inverse of `score_of_total`: +inf at 1, -inf at 0, NaN for NaN."""
    s = np.asarray(score, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return 1.0 + 0.5 * np.log(s / (1.0 - s))


def score_candidates(*args: Any, **kwargs: Any) -> np.ndarray:
    """(K,) float64 scores in (0, 1) of the candidates (higher is better): `score_of_total` of
    `candidate_totals`, which takes the same arguments."""
    return score_of_total(candidate_totals(*args, **kwargs))


def candidate_totals(
    parsed: ParsedPrompt,
    feats: CandidateFeatures,
    shape_prob: dict[str, float] | None,
    reference: tuple[CandidateFeatures, dict[str, float] | None] | None = None,
    weights: ScoringWeights | None = None,
    noun_prior: NounPrior | None = None,
    reference_prior: NounPrior | None = None,
    rivals: RivalReadings | None = None,
    knowledge: Any = None,
    reference_knowledge: Any = None,
) -> np.ndarray:
    """(K,) float64 weighted totals of the score terms of the candidates for `parsed` (module docstring).

    Args:
        parsed: the parsed prompt.
        feats: candidate features with `description_sim` for `parsed.text`.
        shape_prob: p(family | noun) for `parsed.noun`, or None for a generic noun.
        reference: for a relation, the same features with `description_sim` for the reference phrase, and
            p(family | reference noun).
        weights: term weights.
        noun_prior, reference_prior: the library family of the target's / reference's noun, when it names
            one (the metric size term), else None.
        rivals: the candidates read as the library's other families (`RivalReadings`), for a target noun
            that names one of them.
        knowledge, reference_knowledge: what the object-knowledge table knows of the target's / reference's
            noun (`knowledge.KnowledgeMatch`), or None.
    """
    w = weights or ScoringWeights()
    K = len(feats.description_sim)
    if K == 0:
        return np.zeros(0)
    base = _base_terms(parsed, feats, shape_prob, w, noun_prior, knowledge)
    if (
        rivals is not None
        and rivals.others
        and noun_prior is not None
        and not knows_more_than_family(knowledge, noun_prior, w)
    ):
        # another family of the library that explains a candidate better takes from it (module docstring);
        # the nouns alone are compared, so the prompt's other words count the same on both sides
        own = _base_terms(parsed, rivals.own, shape_prob, w, noun_prior)
        best = np.max([_base_terms(parsed, f, p, w, r) for f, p, r in rivals.others], axis=0)
        base = base - w.rival * np.maximum(best - own, 0.0)
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
        ref_base = _base_terms(
            parsed.reference, ref_feats, ref_shape, w, reference_prior, reference_knowledge
        )
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
    return total
