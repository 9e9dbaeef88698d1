"""Match probabilities, contenders and their calibration (`grounding.confidence`)."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.grounding.confidence import (
    ConfidenceModel,
    contenders,
    fit_confidence,
    match_probabilities,
)


def test_probabilities_are_the_softmax_with_none():
    m = ConfidenceModel(temperature=0.5, none_total=1.0)
    p, p_none = match_probabilities(np.array([3.0, 2.0]), m)
    z = np.exp(np.array([3.0, 2.0, 1.0]) / 0.5)
    assert np.allclose([*p, p_none], z / z.sum())
    assert p.sum() + p_none == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("totals", "expected"),
    [
        ([4.0, 1.0], 1),  # clear: p ~ 0.997
        ([3.0, 3.0], 2),  # two equal: ambiguous
        ([3.0, 3.0, 3.0, -2.0], 3),  # three equal and one far off
        ([0.0, -3.0], 0),  # "none" (total 1) likelier than the best
        ([1.2, -5.0], 0),  # the best's only rival within `none_ratio` is "none"
        ([3.0, 2.5], 2),  # odds 2.7:1, within `contender_ratio` (identical objects seen from two places)
        ([], 0),
    ],
)
def test_contenders_known_by_construction(totals, expected):
    m = ConfidenceModel(temperature=0.5, none_total=1.0)
    p, p_none = match_probabilities(np.array(totals, dtype=float), m)
    assert contenders(p, p_none, m) == expected


def test_a_best_likelier_wrong_than_right_is_no_pick():
    # ten weak candidates share the mass: the best at 0.28 has no single rival within half of it, yet it is
    # likelier wrong than right
    m = ConfidenceModel(temperature=1.0, none_total=-10.0, contender_ratio=0.5)
    totals = np.array([1.0] + [0.0] * 5)
    p, p_none = match_probabilities(totals, m)
    assert p[0] < 0.5 and np.all(p[1:] < m.contender_ratio * p[0])
    assert contenders(p, p_none, m) == 0


def test_fit_recovers_the_temperature_of_simulated_choices():
    # prompts whose answer (a candidate or "none") is drawn from the model itself at T = 0.7, "none" at the
    # 2nd percentile of the best totals: the maximum likelihood T comes back within sampling error (2,000
    # prompts: a few percent)
    rng = np.random.default_rng(0)
    all_totals = rng.normal(2.0, 1.0, size=(2000, 4))
    t_none = float(np.quantile(all_totals.max(axis=1), 0.02))
    prompts = []
    for totals in all_totals:
        z = np.exp(np.append(totals, t_none) / 0.7)
        k = rng.choice(5, p=z / z.sum())
        prompts.append((totals, np.arange(4) == k))  # k == 4: "none", no candidate is right
    m = fit_confidence(prompts)
    assert m.temperature == pytest.approx(0.7, rel=0.1)
    best = [float(t.max()) for t, right in prompts if right.any()]
    assert m.none_total == pytest.approx(float(np.quantile(best, 0.02)))


def test_bad_settings_are_refused():
    with pytest.raises(InvalidInputError, match="temperature"):
        ConfidenceModel(temperature=0.0)
    with pytest.raises(InvalidInputError, match="pick_probability"):
        ConfidenceModel(pick_probability=1.5)
    with pytest.raises(InvalidInputError, match="among the candidates"):
        fit_confidence([(np.array([1.0]), np.array([False]))])
