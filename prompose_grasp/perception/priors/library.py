"""`PriorLibrary`: text -> canonical shape prior, the embedded default for the paper's Hunyuan3D step.

How a prior is chosen for a prompt (docs/priors.md):

1. The prompt is embedded with the sentence encoder (MiniLM by default) twice: as given, and with colour,
   size, material and article words removed ("the small red mug" -> "mug"). Its score for a family is the
   highest cosine similarity of either version with any of the family's descriptions.
2. When the best family scores at least `threshold`, that family's mean shape is the prior.
3. Otherwise the word is unknown to the library: a superquadric is fitted to the first frame's observed
   points and becomes the prior ("superquadric"). Without points this is an error that says so.
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.perception.priors.families import FAMILIES, ShapeFamily
from prompose_grasp.perception.priors.prior import (
    DEFAULT_N_POINTS,
    ShapePrior,
    make_prior,
    normalize_to_unit_box,
)
from prompose_grasp.perception.priors.superquadric import (
    SuperquadricFit,
    fit_superquadric,
    superquadric_mesh,
)
from prompose_grasp.perception.text import TextEncoder, default_text_encoder

__all__ = [
    "DEFAULT_MATCH_THRESHOLD",
    "PriorLibrary",
    "articulated_variants",
    "core_phrase",
    "head_noun",
    "round_body_axis",
    "superquadric_prior",
]

log = logging.getLogger(__name__)

#: A family is used when its score (`PriorLibrary.match`) reaches this value; below it the prompt counts as
#: unknown and a superquadric is fitted to the observation. Measured with MiniLM
#: (`python -m prompose_grasp.perception.priors.bench`): 30 everyday objects that no family resembles score
#: at most 0.557 ("spoon" -> plate); 50 of 52 in-library prompts score at least 0.587 ("cookbook" -> book),
#: the other two ("chromebook" 0.519, "thermos flask" 0.411) fall back to a superquadric. 0.58 sits in the
#: gap, nearer its top: retrieving a wrong family (a plate for a spoon) costs more than fitting a
#: superquadric to a known object. docs/priors.md has the full table.
DEFAULT_MATCH_THRESHOLD = 0.58

#: Words that describe an object's look, size, material or place, articles, and command verbs: they do not
#: change its shape family but pull the sentence embedding around, so they are dropped before matching.
_MODIFIERS = frozenset(
    """
    a an the this that these those my your its some one two three please
    red green blue yellow orange purple violet pink brown black white grey gray silver golden gold beige
    cyan magenta turquoise navy maroon dark light bright pale transparent clear colorful colourful striped
    dotted shiny matte metallic
    small smaller smallest big bigger biggest large larger largest tiny huge little medium tall short long
    wide narrow thin thick heavy empty full new old dirty clean
    left right front back leftmost rightmost nearest closest farthest middle top bottom
    pick up put place grab take move bring lift get fetch hand give
    """.split()
)

#: A noun phrase's head noun is the last word before the first of these ("sack of flour" -> "sack",
#: "mug with a handle" -> "mug", "mustard bottle in the bin" -> "bottle").
_PREPOSITIONS = frozenset(
    "of with without for in into on onto from at to by near next behind under over above below beside "
    "between containing filled".split()
)


def core_phrase(prompt: str) -> str:
    """The prompt without look, size, position, article and command words ("the small red mug" -> "mug").

    Returns "" when nothing else is left ("the big red one").
    """
    words = re.findall(r"[A-Za-z0-9][A-Za-z0-9'\-]*", prompt)
    return " ".join(w for w in words if w.lower() not in _MODIFIERS)


def head_noun(phrase: str) -> str:
    """The head noun of an English noun phrase: the last word before the first preposition.

    "tomato soup can" -> "can"; "sack of potatoes" -> "sack"; "" for an empty phrase.
    """
    words = phrase.split()
    for i, w in enumerate(words):
        if w.lower() in _PREPOSITIONS and i > 0:
            return words[i - 1]
    return words[-1] if words else ""


def superquadric_prior(
    fit: SuperquadricFit, *, n_points: int = DEFAULT_N_POINTS, seed: int = 0, prompt: str = ""
) -> ShapePrior:
    """The unit-box prior of a fitted superquadric (x its longer horizontal axis, y up).

    Its symmetry follows from the fit: `spherical` for an equal-sized round one, `y_continuous` for a round
    section (e2 ~ 1 and equal x / z sizes), else `box` (a superquadric is symmetric under 180 degree turns
    about each axis).
    """
    size = fit.size_m
    round_section = abs(fit.e2 - 1.0) < 0.1 and abs(size[0] - size[2]) < 0.05 * max(size[0], size[2])
    if round_section and abs(fit.e1 - 1.0) < 0.1 and abs(size[1] - size[0]) < 0.05 * max(size[0], size[1]):
        symmetry = "spherical"
    elif round_section:
        symmetry = "y_continuous"
    else:
        symmetry = "box"
    mesh = superquadric_mesh(size, fit.e1, fit.e2)
    return make_prior(
        mesh,
        name="superquadric",
        source="superquadric",
        symmetry=symmetry,
        n_points=n_points,
        seed=seed,
        prompt=prompt,
        typical_size_m=size,
    )


#: Articulated variants built so far, by (family, label, n_points, seed): a few ms each to build and sample.
_VARIANTS: dict[tuple[str, str, int, int], ShapePrior] = {}
_VARIANTS_LOCK = threading.Lock()


def _library_family(prior: ShapePrior, with_variants: bool = False) -> ShapeFamily | None:
    """The built-in family `prior` was made from (`source == "library:<family>"`; with `with_variants`, its
    articulated variants' `"library:<family>:<label>"` too), or None (a user's mesh, a superquadric)."""
    if not isinstance(prior, ShapePrior):
        raise InvalidInputError(f"prior must be a ShapePrior, got {type(prior).__name__}")
    own = f"library:{prior.name}"
    if prior.source == own or (with_variants and prior.source.startswith(own + ":")):
        return FAMILIES.get(prior.name)
    return None


def articulated_variants(prior: ShapePrior, seed: int = 0) -> tuple[ShapePrior, ...]:
    """The other articulations of a library family's prior (a laptop's screen at other openings), or ().

    Only priors of the built-in families (`source == "library:<family>"`, `families.FAMILIES`) with
    `ShapeFamily.articulations` have variants; each has the same name, symmetry and point count as `prior`,
    its own unit-box normalisation and typical size, and source `"library:<family>:<label>"`. Built once per
    process and kept.
    """
    family = _library_family(prior)
    if family is None or not family.articulations:
        return ()
    out = []
    for label, build in family.articulations:
        key = (family.name, label, prior.n_points, int(seed))
        with _VARIANTS_LOCK:
            variant = _VARIANTS.get(key)
        if variant is None:
            variant = make_prior(
                build(),
                name=family.name,
                source=f"library:{family.name}:{label}",
                symmetry=family.symmetry,
                n_points=prior.n_points,
                seed=seed,
                prompt=prior.prompt,
                matched_text=prior.matched_text,
                score=prior.score,
            )
            with _VARIANTS_LOCK:
                _VARIANTS[key] = variant
        out.append(variant)
    return tuple(out)


#: family name -> unit-box (x, z) of its round body's axis (`round_body_axis`), computed once.
_BODY_AXES: dict[str, np.ndarray] = {}


def round_body_axis(prior: ShapePrior) -> np.ndarray | None:
    """(2,) unit-box (x, z) of the vertical axis of the prior's round main body, or None.

    Only library families with `ShapeFamily.round_body_axis_m` (the mug: its body is round about this axis
    and only the handle, towards +x, breaks the symmetry) have one. The family's mesh is normalised as the
    prior is (`prior.normalize_to_unit_box`), so the axis lands where the prior's body is.
    """
    family = _library_family(prior)
    if family is None or family.round_body_axis_m is None:
        return None
    with _VARIANTS_LOCK:
        axis = _BODY_AXES.get(family.name)
    if axis is None:
        _, centre, extents = normalize_to_unit_box(family.build())
        xz_m = np.asarray(family.round_body_axis_m, dtype=np.float64)
        axis = (xz_m - centre[[0, 2]]) / extents[[0, 2]]
        axis.setflags(write=False)
        with _VARIANTS_LOCK:
            _BODY_AXES[family.name] = axis
    return axis


def aspect_weight_factors(prior: ShapePrior) -> np.ndarray:
    """(3,) the prior's family's `ShapeFamily.aspect_weight_factors` for the extent pairs (x:y, y:z, x:z),
    its articulated variants' too; ones for a prior of no library family (a user's mesh, a superquadric)."""
    family = _library_family(prior, with_variants=True)
    if family is None:
        return np.ones(3)
    return np.asarray(family.aspect_weight_factors, dtype=np.float64)


class PriorLibrary:
    """Text-retrieved canonical shape priors from parametric families, with a superquadric fallback.

    Args:
        encoder: sentence encoder for matching; default `default_text_encoder("cpu")` (loaded on first use).
        threshold: minimum best-family cosine score to use a family (see `DEFAULT_MATCH_THRESHOLD`).
        families: the families to offer (default: all of `families.FAMILIES`).

    Meshes and description embeddings are built on first use and kept; priors are cheap after that.
    """

    def __init__(
        self,
        encoder: TextEncoder | None = None,
        threshold: float = DEFAULT_MATCH_THRESHOLD,
        families: Mapping[str, ShapeFamily] | None = None,
    ):
        if not (isinstance(threshold, int | float) and -1.0 <= float(threshold) <= 1.0):
            raise InvalidInputError(f"threshold must be a cosine similarity in [-1, 1], got {threshold!r}")
        fams = dict(FAMILIES if families is None else families)
        if not fams:
            raise InvalidInputError("families is empty; a library needs at least one family")
        self._families = fams
        self._encoder = encoder
        self.threshold = float(threshold)
        self._lock = threading.Lock()
        self._meshes: dict[str, trimesh.Trimesh] = {}
        # Surface sampling costs tens of ms; a family's samples depend only on (family, n_points, seed).
        self._sampled: dict[tuple[str, int, int], ShapePrior] = {}
        self._desc_texts: list[str] = []
        self._desc_family: np.ndarray | None = None
        self._desc_emb: np.ndarray | None = None

    @property
    def families(self) -> tuple[str, ...]:
        """Names of the families on offer."""
        return tuple(self._families)

    def family(self, name: str) -> ShapeFamily:
        """The `ShapeFamily` called `name` (`UnknownNameError` lists the names)."""
        try:
            return self._families[name]
        except KeyError:
            raise UnknownNameError("shape family", name, self._families) from None

    @property
    def encoder(self) -> TextEncoder:
        if self._encoder is None:
            self._encoder = default_text_encoder("cpu")
        return self._encoder

    def _description_embeddings(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        with self._lock:
            if self._desc_emb is None:
                names = list(self._families)
                texts, owner = [], []
                for i, name in enumerate(names):
                    for d in self._families[name].descriptions:
                        texts.append(d)
                        owner.append(i)
                self._desc_texts = texts
                self._desc_family = np.asarray(owner)
                self._desc_emb = np.asarray(self.encoder.encode(texts), dtype=np.float64)
            assert self._desc_family is not None
            return self._desc_texts, self._desc_family, self._desc_emb

    def _scores(self, prompt: str) -> list[tuple[str, float, str]]:
        """(family, score, best description of the phrase) for every family, best first."""
        if not isinstance(prompt, str) or not prompt.strip():
            raise InvalidInputError(f"prompt must be a non-blank str, got {prompt!r}")
        texts, owner, emb = self._description_embeddings()
        phrase = core_phrase(prompt) or prompt.strip()
        head = head_noun(phrase)
        variants = [phrase] if head.lower() == phrase.lower() else [phrase, head]
        q = np.asarray(self.encoder.encode(variants), dtype=np.float64)
        sims = q @ emb.T  # (variants, descriptions); rows are unit vectors: dot = cosine
        out = []
        for i, name in enumerate(self._families):
            idx = np.flatnonzero(owner == i)
            best_per_variant = sims[:, idx].max(axis=1)
            j = idx[int(np.argmax(sims[0, idx]))]
            out.append((name, float(best_per_variant.mean()), texts[j]))
        out.sort(key=lambda r: -r[1])
        return out

    def match(self, prompt: str) -> list[tuple[str, float]]:
        """(family, score) for every family, best first.

        The score is the mean of two cosine similarities, each the best over the family's descriptions: one
        of the prompt's core phrase (`core_phrase`), one of its head noun (`head_noun`); they are the same
        when the core phrase is one word.
        """
        return [(name, score) for name, score, _ in self._scores(prompt)]

    def mesh(self, family: str) -> trimesh.Trimesh:
        """The family's mean shape in metres, canonical frame (built once, then a copy is returned)."""
        fam = self.family(family)
        with self._lock:
            m = self._meshes.get(family)
            if m is None:
                m = fam.build()
                self._meshes[family] = m
        return m.copy()

    def family_prior(
        self,
        family: str,
        *,
        n_points: int = DEFAULT_N_POINTS,
        seed: int = 0,
        prompt: str = "",
        matched_text: str = "",
        score: float = float("nan"),
    ) -> ShapePrior:
        """The prior of a named family (no text matching): unit-box mesh and `n_points` seeded samples."""
        fam = self.family(family)
        key = (fam.name, int(n_points), int(seed))
        sampled = self._sampled.get(key)
        if sampled is None:
            sampled = make_prior(
                self.mesh(family),
                name=fam.name,
                source=f"library:{fam.name}",
                symmetry=fam.symmetry,
                n_points=n_points,
                seed=seed,
            )
            self._sampled[key] = sampled
        return replace(sampled, prompt=prompt, matched_text=matched_text, score=score)

    def generate(
        self,
        prompt: str,
        observation_points: ArrayLike | None = None,
        up: ArrayLike | None = None,
        *,
        support_offset_m: float | None = None,
        n_points: int = DEFAULT_N_POINTS,
        seed: int = 0,
    ) -> ShapePrior:
        """The canonical prior for `prompt`: the best family, or a superquadric fitted to the observation.

        Args:
            prompt: the object phrase ("the yellow carton"); a whole command also works but its other nouns
                ("... in the bin") compete with the object's.
            observation_points: (N, 3) float, metres: the target's points in the first frame (e.g. masked
                depth back-projected into the camera frame), used only when no family matches.
            up: (3,) the object's up direction in the points' frame (e.g. `T_cam_support[:3, 2]`); default
                (0, -1, 0), up for a level OpenCV camera.
            support_offset_m: with `up` the unit normal n of the plane the object stands on, its d
                (`n . x + d = 0`): a fitted superquadric then rests on the plane
                (`superquadric.fit_superquadric`).
            n_points, seed: surface samples of the prior and their seed.

        Raises:
            InvalidInputError: no family reaches `threshold` and no observation was given.
        """
        scores = self._scores(prompt)
        best, score, text = scores[0]
        if score >= self.threshold:
            log.debug("prior for %r: family %s (%.3f via %r)", prompt, best, score, text)
            return self.family_prior(
                best, n_points=n_points, seed=seed, prompt=prompt, matched_text=text, score=score
            )
        if observation_points is None:
            raise InvalidInputError(
                f"prompt {prompt!r} matches no shape family well enough (best {best} {score:.2f} < threshold "
                f"{self.threshold:.2f}); pass observation_points to fit a superquadric, pass a CAD mesh "
                f"(from_mesh), or name one of: {', '.join(self._families)}"
            )
        log.info(
            "prompt %r matches no family (best %s %.2f < %.2f): fitting a superquadric",
            prompt,
            best,
            score,
            self.threshold,
        )
        fit = fit_superquadric(
            observation_points,
            up=(0.0, -1.0, 0.0) if up is None else up,
            support_offset_m=None if up is None else support_offset_m,
        )
        return superquadric_prior(fit, n_points=n_points, seed=seed, prompt=prompt)

    def describe(self) -> Sequence[tuple[str, str, str, tuple[str, ...]]]:
        """(family, symmetry, frame, descriptions) rows, for documentation and CLIs."""
        return [(f.name, f.symmetry, f.frame, f.descriptions) for f in self._families.values()]
