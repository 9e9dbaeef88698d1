"""Match probabilities from score totals, and how many candidates contend for a prompt.

The grounder's score terms add up to a total per candidate (`score.candidate_totals`). Which candidate the
prompt names is read as a choice among the candidates and "none of them": a softmax of the totals with a
temperature, beside a fixed total for "none",

    p_i = exp(t_i / T) / (exp(t_none / T) + sum_j exp(t_j / T)),

so a candidate's probability is high only when its total stands clear of every other and of "none". T and
t_none are fitted on generated scenes whose true object is known (the grounding benchmark's records,
`fit_confidence`): T by maximum likelihood, so that the probabilities match how often the best is right;
t_none so that "nothing fits" rarely turns away an object that is there (docs/grounding.md, "Object
knowledge and confidence").

Contenders (`contenders`): 0 when "none" is likelier than the best candidate, or is the best's only rival
within `none_ratio` of it, or the best alone is under `pick_probability` (nothing fits the words, or
whether the one that might is the object is a guess); 1 when the best is clear (its probability at least
`clear_probability`, or nothing else within `contender_ratio` of it); else the number of candidates within
`contender_ratio` of the best: the prompt does not tell them apart, and choosing one would be a guess.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from prompose_grasp.errors import InvalidInputError

__all__ = ["ConfidenceModel", "contenders", "fit_confidence", "match_probabilities"]


@dataclass(frozen=True)
class ConfidenceModel:
    """Calibration of the match probabilities (module docstring).

    Attributes:
        temperature: T, in units of the score total.
        none_total: t_none, the total of "none of the candidates".
        clear_probability: a best candidate this probable is chosen whatever the runner-up.
        contender_ratio: candidates whose probability is at least this fraction of the best's contend with
            it (when the best is not clear). 0.3, odds within about 3:1, a total T ln 3.3 = 0.7 apart: two
            identical objects seen from two places differ by up to about 0.5 (the visible depth of a round
            thing, a corner hidden), and the pair must still read as a pair.
        none_ratio: "none of them" contends with a lone best candidate at this fraction of its probability
            (0.5: odds within 2:1; "none" has a fixed total, no view noise to allow for).
        pick_probability: a best candidate without contenders is chosen only at this probability or more
            (0.5: likelier right than wrong).
    """

    # fitted on generated scenes (sim.dataset seed 41, 40 scenes x 2 frames, 644 prompts): the grounding
    # bench `--data DIR --json R.json`, then `--fit-confidence R.json` (docs/grounding.md, "Object knowledge
    # and confidence")
    temperature: float = 0.59
    none_total: float = 0.88
    clear_probability: float = 0.75
    contender_ratio: float = 0.3
    none_ratio: float = 0.5
    pick_probability: float = 0.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.temperature) and self.temperature > 0):
            raise InvalidInputError(f"temperature must be finite and > 0, got {self.temperature}")
        if not np.isfinite(self.none_total):
            raise InvalidInputError(f"none_total must be finite, got {self.none_total}")
        for name in ("clear_probability", "contender_ratio", "none_ratio", "pick_probability"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise InvalidInputError(f"{name} must be in (0, 1], got {getattr(self, name)}")


def match_probabilities(totals: np.ndarray, model: ConfidenceModel) -> tuple[np.ndarray, float]:
    """(K,) probability of each candidate and the probability of "none", from (K,) score totals."""
    t = np.asarray(totals, dtype=np.float64)
    z = np.append(t, model.none_total) / model.temperature
    z = np.exp(z - z.max())
    p = z / z.sum()
    return p[:-1], float(p[-1])


def contenders(probabilities: np.ndarray, p_none: float, model: ConfidenceModel) -> int:
    """How many of the best candidates fit about equally well (module docstring); probabilities best first
    or in any order."""
    p = np.sort(np.asarray(probabilities, dtype=np.float64))[::-1]
    if len(p) == 0 or p[0] < p_none:
        return 0
    if p[0] >= model.clear_probability:
        return 1
    n = max(1, int(np.count_nonzero(p >= model.contender_ratio * p[0])))
    if n == 1 and (p_none >= model.none_ratio * p[0] or p[0] < model.pick_probability):
        # "none of them" contends with the only candidate, or the best is likelier wrong than right (many
        # weak candidates share the rest): whether the object is there at all is a guess
        return 0
    return n


def fit_confidence(
    prompts: list[tuple[np.ndarray, np.ndarray]],
    base: ConfidenceModel | None = None,
    none_quantile: float = 0.02,
) -> ConfidenceModel:
    """T by maximum likelihood, t_none from the best totals of prompts whose object is in view.

    t_none is the `none_quantile` quantile of those best totals: "nothing fits" then turns away a prompt
    whose object is there at most that often on the calibration data. It is not fitted to prompts for absent
    objects: in a tabletop scene an absent kind often has a fair stand-in (a carton is a box, a cup much like
    a mug), and such prompts would pull t_none up until present objects were refused.

    Args:
        prompts: per prompt whose object is in the frame, the (K,) totals and a (K,) bool of the candidates
            that are that object (a prompt whose object no candidate matches counts for "none").
        base: the other settings to keep (`clear_probability`, `contender_ratio`).
        none_quantile: see above.
    """
    from scipy.optimize import minimize_scalar

    base = base or ConfidenceModel()
    best = [float(np.max(t)) for t, right in prompts if len(t) and np.any(right)]
    if not best:
        raise InvalidInputError("fit_confidence needs prompts whose object is among the candidates")
    t0 = float(np.quantile(best, none_quantile))

    def nll(log_T: float) -> float:
        T = float(np.exp(log_T))
        total = 0.0
        for totals, right in prompts:
            z = np.append(totals, t0) / T
            m = z.max()
            lse = m + np.log(np.exp(z - m).sum())
            good = np.append(right, not np.any(right))
            total -= np.log(np.exp(z[good] - lse).sum())
        return total

    res = minimize_scalar(nll, bounds=(np.log(0.05), np.log(5.0)), method="bounded")
    return dataclasses.replace(base, temperature=float(np.exp(res.x)), none_total=t0)
