"""The object-knowledge table: its schema, retrieval by name, and the score terms it gives."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.grounding.describe import PALETTE
from prompose_grasp.perception.grounding.language import parse_prompt
from prompose_grasp.perception.grounding.score import (
    SHAPE_FIT,
    CandidateFeatures,
    ScoringWeights,
    height_seen_in_full,
    knowledge_size_term,
    knowledge_terms,
)
from prompose_grasp.perception.knowledge import COARSE_SHAPES, ObjectKnowledge, load_table
from prompose_grasp.perception.knowledge.table import _joined


@pytest.fixture(scope="module")
def knowledge():
    from prompose_grasp.perception.text import default_text_encoder

    return ObjectKnowledge(default_text_encoder())


def test_the_shipped_table_is_large_valid_and_covers_every_shape():
    entries = load_table()  # validates every entry (schema, sorted ranges, palette names)
    assert len(entries) >= 300
    assert len({e.name for e in entries}) == len(entries)
    assert {e.shape for e in entries} == set(COARSE_SHAPES)
    for e in entries:
        assert np.all(e.size_lo_m <= e.size_hi_m)
        assert set(e.colours) <= set(PALETTE)


def _write(tmp_path, entries):
    path = tmp_path / "objects.json"
    path.write_text(json.dumps(entries))
    return path


_GOOD = {
    "name": "widget",
    "synonyms": ["gizmo"],
    "category": "household",
    "size_m": [[0.1, 0.2], [0.05, 0.08], [0.02, 0.03]],
    "colours": ["red"],
    "shape": "box",
    "features": [],
    "rigid": True,
}


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"size_m": [[0.02, 0.03], [0.05, 0.08], [0.1, 0.2]]}, "largest first"),
        ({"size_m": [[0.2, 0.1], [0.05, 0.08], [0.02, 0.03]]}, "min > max"),
        ({"colours": ["mauve"]}, "mauve"),
        ({"shape": "blob"}, "blob"),
        ({"category": "space"}, "space"),
        ({"rigid": "yes"}, "rigid"),
        ({"extra": 1}, "exactly the keys"),
    ],
)
def test_a_bad_entry_is_refused_naming_what_is_wrong(tmp_path, change, words):
    with pytest.raises(InvalidInputError, match=words):
        load_table(_write(tmp_path, [{**_GOOD, **change}]))


def test_a_name_given_twice_and_a_missing_file_are_refused(tmp_path):
    with pytest.raises(InvalidInputError, match="twice"):
        load_table(_write(tmp_path, [_GOOD, {**_GOOD, "name": "doohickey", "synonyms": ["gizmo"]}]))
    with pytest.raises(InvalidInputError, match="cannot read"):
        load_table(tmp_path / "nothing.json")


@pytest.mark.parametrize(
    ("noun", "name"),
    [
        ("tuna can", "tuna can"),  # a name
        ("can of tuna", "tuna can"),  # a synonym
        ("mustard bottle", "mustard bottle"),
        ("coffee mug", "mug"),
        ("banana", "banana"),
        ("sugar box", "sugar box"),
        ("gelatin box", "gelatin box"),
    ],
)
def test_names_and_synonyms_retrieve_their_entry_at_full_weight(knowledge, noun, name):
    match = knowledge.lookup(noun)
    assert match is not None and match.entry.name == name
    assert match.weight == 1.0


def test_an_unseen_name_falls_to_its_nearest_entries_with_less_weight(knowledge):
    # no name or synonym of the table: the nearest kinds (soft toys), weighted down
    match = knowledge.lookup("plush dolphin")
    assert match is not None and 0.0 < match.weight < 1.0
    assert all(e.category == "toy" for e in match.entries)
    assert not match.entries[0].rigid
    # a word that names nothing the table holds says nothing
    assert knowledge.lookup("thingamajig") is None
    assert knowledge.lookup("") is None


def test_joined_entries_span_both_ranges_and_keep_colours_only_when_all_have_them():
    a = load_table()[0]
    b = next(e for e in load_table() if not e.colours)
    m = _joined("x", (a, b), 0.7, 0.5)
    assert np.allclose(m.size_lo_m, np.minimum(a.size_lo_m, b.size_lo_m))
    assert np.allclose(m.size_hi_m, np.maximum(a.size_hi_m, b.size_hi_m))
    assert m.colours == ()  # b comes in any colour


def test_size_term_inside_the_range_is_one_and_outside_follows_the_log_normal():
    w = ScoringWeights()
    lo, hi = np.array([0.10, 0.06, 0.04]), np.array([0.12, 0.07, 0.05])
    inside = knowledge_size_term(np.array([[0.11, 0.065, 0.045]]), lo, hi, w)
    assert inside[0] == pytest.approx(1.0)
    # every extent 20 % over the top of its range (plus the slack): r = log 1.2 on each of the three axes,
    # summed
    e = 1.2 * hi + w.knowledge_slack_m
    term = knowledge_size_term(e[None, :], lo, hi, w)[0]
    expected = 2.0 * np.exp(-0.5 * 3.0 * (np.log(1.2) / w.knowledge_over_sigma) ** 2) - 1.0
    assert term == pytest.approx(expected)
    # orientation-free: the same extents in another order score the same
    assert knowledge_size_term(e[None, ::-1], lo, hi, w)[0] == pytest.approx(term)
    # the same log ratio below the range is judged with the wider under-sigma (occlusion and self-occlusion
    # only shrink what is measured)
    small = knowledge_size_term((lo / 1.2 - w.knowledge_slack_m)[None, :], lo, hi, w)[0]
    assert small > term


def test_an_extent_seen_in_full_is_judged_strictly_for_being_too_small():
    """A cracker box (16 x 6 x 21 cm standing) against the cereal-box range (25-34 cm long): seen whole,
    its 21 cm height is its own and falls 0.13 in log short of the range's bottom (with the slack): the
    strict sigma takes half the term for that (0.87 -> 0.39); with its outline hidden it may be part of a
    taller box and keeps the lenient sigma. Inside the range both are 1. Only a height is ever sure."""
    w = ScoringWeights()
    lo, hi = np.array([0.25, 0.17, 0.05]), np.array([0.34, 0.23, 0.08])
    cracker = np.array([[0.16, 0.06, 0.21]])
    r = np.log((0.21 + w.knowledge_slack_m) / lo[0])
    hidden = knowledge_size_term(cracker, lo, hi, w, height_seen=np.zeros(1))[0]
    whole = knowledge_size_term(cracker, lo, hi, w, height_seen=np.ones(1))[0]
    assert hidden == pytest.approx(knowledge_size_term(cracker, lo, hi, w)[0])  # not judged: as before
    assert whole == pytest.approx(2.0 * np.exp(-0.5 * (r / w.knowledge_under_sigma_seen) ** 2) - 1.0)
    assert whole < hidden - 0.4
    cereal = np.array([[0.21, 0.07, 0.30]])
    assert knowledge_size_term(cereal, lo, hi, w, height_seen=np.ones(1))[0] == pytest.approx(1.0)
    # the same box lying (21 cm its footprint's length) is not judged strictly: a footprint is never sure
    lying = np.array([[0.21, 0.16, 0.06]])
    assert knowledge_size_term(lying, lo, hi, w, height_seen=np.ones(1))[0] == pytest.approx(hidden)
    # seen whole, sure of the height only (a footprint loses thin parts and a round body's far half)
    grey = np.zeros(len(PALETTE))
    feats = dataclasses.replace(
        _feats([[0.1, 0.05, 0.1]] * 3, ["box", "cylinder", "box"], [grey] * 3),
        outline_hidden=np.array([0.0, w.knowledge_outline_hidden, 1.0]),
    )
    np.testing.assert_allclose(height_seen_in_full(feats, w), [1, 0, 0])
    assert height_seen_in_full(_feats([[0.1, 0.05, 0.1]], ["box"], [grey]), w) is None


def test_a_kind_that_lies_is_judged_with_its_height_as_its_shortest_extent():
    w = ScoringWeights()
    banana = next(e for e in load_table() if e.name == "banana")
    assert "lies" in banana.features
    lo, hi = banana.size_lo_m, banana.size_hi_m
    lying = np.array([0.20, 0.05, 0.035])  # footprint 20 x 5 cm, 3.5 cm high: inside every range
    standing = np.array([0.05, 0.035, 0.20])  # the same extents, 20 cm high: a bottle's, not a banana's
    for e in (lying, standing):  # orientation-free for a kind that stands as well as it lies
        assert knowledge_size_term(e[None, :], lo, hi, w)[0] == pytest.approx(1.0)
    assert knowledge_size_term(lying[None, :], lo, hi, w, lies=True)[0] == pytest.approx(1.0)
    # 20 cm high against at most 4 cm (+ 1 cm slack): r = log(0.19 / 0.04) on the height, and the 5 cm
    # footprint length is under the 15 cm range's bottom: the log-normal of both
    r_over = np.log((0.20 - w.knowledge_slack_m) / hi[2])
    r_under = np.log((0.05 + w.knowledge_slack_m) / lo[0])
    d2 = (r_over / w.knowledge_over_sigma) ** 2 + (r_under / w.knowledge_under_sigma[0]) ** 2
    term = knowledge_size_term(standing[None, :], lo, hi, w, lies=True)[0]
    assert term == pytest.approx(2.0 * np.exp(-0.5 * d2) - 1.0)
    assert term < -0.99
    # the footprint's two extents are compared largest first whichever way they come
    assert knowledge_size_term(lying[None, [1, 0, 2]], lo, hi, w, lies=True)[0] == pytest.approx(1.0)


def test_a_match_lies_only_when_every_entry_it_joins_does(knowledge):
    assert knowledge.lookup("banana").lies and knowledge.lookup("screwdriver").lies
    assert not knowledge.lookup("flashlight").lies  # it stands on its end as well
    a = next(e for e in load_table() if e.name == "knife")
    b = next(e for e in load_table() if e.name == "flashlight")
    assert _joined("x", (a,), 0.7, 0.5).lies and not _joined("x", (a, b), 0.7, 0.5).lies


def _feats(extents, families, shares):
    K = len(extents)
    return CandidateFeatures(
        description_sim=np.zeros(K),
        colour_shares=np.asarray(shares, dtype=np.float64),
        palette=PALETTE,
        size_classes=("medium",) * K,
        families=tuple(families),
        extents_m=np.asarray(extents, dtype=np.float64),
        plane_xy_m=np.zeros((K, 2)),
        distance_m=np.ones(K),
    )


def test_knowledge_terms_prefer_the_size_colour_and_shape_of_the_named_object(knowledge):
    match = knowledge.lookup("mustard bottle")
    yellow, red = np.zeros(len(PALETTE)), np.zeros(len(PALETTE))
    yellow[PALETTE.index("yellow")], red[PALETTE.index("red")] = 1.0, 1.0
    typical = match.entry.typical_size_m
    feats = _feats([typical, typical, 3.0 * typical], ["cylinder"] * 3, [yellow, red, yellow])
    terms = knowledge_terms(parse_prompt("the mustard bottle"), feats, match, ScoringWeights())
    assert terms[0] > terms[1] and terms[0] > terms[2]
    # a colour word in the prompt is the user's, and the typical colours then say nothing
    told = knowledge_terms(parse_prompt("the red mustard bottle"), feats, match, ScoringWeights())
    assert told[0] == pytest.approx(told[1])


def test_a_long_thin_kind_standing_up_reads_as_long_and_thin(knowledge):
    # A flashlight stands on its end (its footprint reads cylindrical, 3 x 3 cm under 14 cm) or lies (its
    # footprint reads elongated): both are the long thin kind the table knows; a short can of the same
    # family is not.
    match = knowledge.lookup("flashlight")
    assert "elongated" in match.shapes
    grey = np.zeros(len(PALETTE))
    feats = _feats(
        [[0.03, 0.03, 0.14], [0.14, 0.03, 0.03], [0.07, 0.07, 0.08]],
        ["cylinder", "elongated", "cylinder"],
        [grey, grey, grey],
    )
    w = dataclasses.replace(ScoringWeights(), knowledge_size=0.0, knowledge_colour=0.0)
    terms = knowledge_terms(parse_prompt("the flashlight"), feats, match, w)
    assert terms[0] == pytest.approx(terms[1]) and terms[0] > terms[2]


def test_a_yellow_bottle_standing_is_no_banana_but_one_lying_could_be(knowledge):
    # The same yellow 19 x 6 x 4 cm object standing on its end and lying on its side: both are as long and as
    # yellow as a banana, but a banana does not stand; a flashlight does, and is judged the same either way.
    yellow = np.zeros(len(PALETTE))
    yellow[PALETTE.index("yellow")] = 1.0
    feats = _feats([[0.06, 0.04, 0.19], [0.19, 0.06, 0.04]], ["cylinder", "elongated"], [yellow, yellow])
    banana = knowledge_terms(parse_prompt("the banana"), feats, knowledge.lookup("banana"), ScoringWeights())
    # the standing one's 19 cm height is 4 cm at most for a banana (+1 cm slack): most of the size term's
    # swing of 2 x 1.5
    assert banana[1] - banana[0] > 2.0
    light = knowledge_terms(
        parse_prompt("the flashlight"), feats, knowledge.lookup("flashlight"), ScoringWeights()
    )
    assert light[0] == pytest.approx(light[1])


def test_shape_fit_rows_cover_every_coarse_shape_and_stay_in_range():
    assert set(SHAPE_FIT) == set(COARSE_SHAPES)
    for row in SHAPE_FIT.values():
        assert all(-1.0 <= v <= 1.0 for v in row.values())
        assert max(row.values()) == 1.0 or all(v == 0.0 for v in row.values())


class _CountingEncoder:
    """The shared MiniLM, counting the texts it is asked to embed."""

    def __init__(self, inner):
        self.inner, self.texts = inner, 0
        self.model_path, self.dim = getattr(inner, "model_path", ""), inner.dim

    def encode(self, texts):
        self.texts += 1 if isinstance(texts, str) else len(texts)
        return self.inner.encode(texts)


def test_table_embeddings_are_cached_between_processes_and_a_bad_cache_is_only_a_log_line(
    tmp_path, monkeypatch, knowledge, caplog
):
    from prompose_grasp.perception.knowledge import table

    monkeypatch.setenv("PROMPOSE_GRASP_CACHE", str(tmp_path / "cache"))
    first = _CountingEncoder(knowledge.encoder)
    k1 = ObjectKnowledge(first)
    k1.warm_up()
    n_texts = sum(1 + len(e.synonyms) for e in k1.entries)
    assert first.texts == n_texts + 1  # every name and synonym, and the cache key's probe
    (cached,) = (tmp_path / "cache").glob("knowledge-*.npy")
    second = _CountingEncoder(knowledge.encoder)
    k2 = ObjectKnowledge(second)
    k2.warm_up()
    assert second.texts == 1  # the probe only: the table came from the cache, the same numbers
    assert np.array_equal(k1._embeddings(), k2._embeddings())
    assert k2.lookup("can of tuna").entry.name == "tuna can"
    # a corrupt entry is embedded again (and rewritten), with a log line, not an error
    cached.write_bytes(b"not an array")
    caplog.set_level("INFO", logger=table.__name__)
    third = _CountingEncoder(knowledge.encoder)
    ObjectKnowledge(third).warm_up()
    assert third.texts == n_texts + 1 and "unreadable" in caplog.text
    # a cache that cannot be written is skipped
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("PROMPOSE_GRASP_CACHE", str(blocker / "sub"))
    ObjectKnowledge(_CountingEncoder(knowledge.encoder)).warm_up()
    assert "not written" in caplog.text


def test_a_product_the_table_names_more_closely_than_the_library_is_judged_by_its_entry():
    """A tuna can is a short cylinder (8.5 x 4 cm) whose footprint reads flat; the library's can family
    expects a taller cylinder. For "the tuna can" the entry's size and coarse shape stand in for the family's
    typical size and shape, so the flat-reading tuna can beats a slim cylinder of a marker's size; for the
    family's own name ("the can") the family's terms still count."""
    from prompose_grasp.perception.grounding.grounder import Grounder
    from prompose_grasp.perception.grounding.score import candidate_totals, knows_more_than_family
    from prompose_grasp.perception.grounding.types import GroundingConfig

    g = Grounder(GroundingConfig())
    grey = np.zeros(len(PALETTE))
    grey[PALETTE.index("grey")] = 1.0
    feats = _feats([[0.086, 0.084, 0.04], [0.033, 0.019, 0.114]], ["flat", "cylinder"], [grey, grey])
    w = g.weights

    def totals(prompt: str) -> tuple[np.ndarray, bool]:
        parsed = parse_prompt(prompt)
        prior, match = g._prior_for(parsed, True), g._knowledge_for(parsed)
        t = candidate_totals(parsed, feats, g._shape_prob(parsed), None, w, noun_prior=prior, knowledge=match)
        return t, knows_more_than_family(match, prior, w)

    tuna, closer = totals("the tuna can")
    assert closer and tuna[0] > tuna[1]
    _, closer = totals("the can")
    assert not closer


def test_a_product_named_by_a_family_alias_is_sized_by_its_entry():
    """ "soda can" and "cereal box" are aliases of the library's can and box families and entries of the
    table: the family's typical object is every can's or box's. A round family stands on its base, so the
    soda can's entry (12-12.4 x 6.5-6.7 x 6.5-6.7 cm) becomes a 6.6 cm footprint under 12.2 cm; a box rests
    on any face, so no typical box is left to judge by (the entry's range alone). The families' own names,
    and a mug (whose entry's longest extent is across its handle, no footprint of a round body), keep the
    family's extents."""
    from prompose_grasp.perception.grounding.grounder import Grounder

    g = Grounder()
    can, box, mug = g.noun_prior("can"), g.noun_prior("box"), g.noun_prior("mug")
    soda = g.noun_prior("soda can")
    assert soda is not None and soda.family == "can"
    np.testing.assert_allclose(soda.typical_extent_m, [0.066, 0.066, 0.122])
    assert can is not None and can.typical_extent_m[2] == pytest.approx(0.115)  # the family's own
    cereal = g.noun_prior("cereal box")
    assert cereal is not None and cereal.family == "box" and cereal.typical_extent_m is None
    assert box is not None and box.typical_extent_m is not None
    coffee_mug = g.noun_prior("coffee mug")
    assert coffee_mug is not None and mug is not None
    np.testing.assert_array_equal(coffee_mug.typical_extent_m, mug.typical_extent_m)


@pytest.mark.parametrize("animal", ["elephant", "giraffe", "lion"])
def test_an_animal_named_on_a_table_is_a_toy_figure(knowledge, animal):
    """On a table an animal's name means a figure of it: the toy-animal entry (5-20 cm), near full weight."""
    match = knowledge.lookup(animal)
    assert match is not None and match.weight > 0.9 and match.entry.name == "toy animal"


def test_a_noun_without_a_library_family_is_shaped_by_its_entry_not_by_how_the_word_reads():
    """ "elephant" has no family in the prior library; its words read nearest "a long thin object" among the
    family sentences, which would favour a banana-shaped candidate. The table says a toy animal is irregular:
    a candidate reading long and thin and one reading cylindrical, alike in everything else, tie. For "the
    knife" (elongated in the table) the long thin one wins."""
    from prompose_grasp.perception.grounding.grounder import Grounder
    from prompose_grasp.perception.grounding.score import candidate_totals
    from prompose_grasp.perception.grounding.types import GroundingConfig

    g = Grounder(GroundingConfig())
    grey = np.zeros(len(PALETTE))
    grey[PALETTE.index("grey")] = 1.0

    def totals(prompt: str, extents: list[list[float]]) -> np.ndarray:
        parsed = parse_prompt(prompt)
        prior, match = g._prior_for(parsed, True), g._knowledge_for(parsed)
        assert prior is None and match is not None and match.weight > 0.9
        feats = _feats(extents, ["elongated", "cylinder"], [grey, grey])
        return candidate_totals(parsed, feats, g._shape_prob(parsed), None, g.weights, knowledge=match)

    elephant = totals("the elephant", [[0.12, 0.06, 0.09]] * 2)
    assert elephant[0] == pytest.approx(elephant[1])
    knife = totals("the knife", [[0.21, 0.02, 0.01], [0.21, 0.09, 0.09]])
    assert knife[0] > knife[1]


def test_a_handle_speaks_for_or_against_a_noun_by_its_table_entry_when_the_library_has_no_family():
    """The library has no family for "apple", "kettle" or "elephant"; the table says an apple is a plain
    round body, a kettle has a handle, a toy animal is irregular. Of two candidates alike but for a handle
    seen on one (a red mug beside a red apple, both 9 cm), the handle costs "the apple" the handle weight and
    gains it for "the kettle"; for "the elephant" (a toy's arm reads like a handle) it says nothing."""
    from prompose_grasp.perception.grounding.grounder import Grounder
    from prompose_grasp.perception.grounding.score import candidate_totals, knowledge_handle_sign
    from prompose_grasp.perception.grounding.types import GroundingConfig

    g = Grounder(GroundingConfig())
    red = np.zeros(len(PALETTE))
    red[PALETTE.index("red")] = 1.0
    feats = dataclasses.replace(
        _feats([[0.09, 0.085, 0.08]] * 2, ["cylinder"] * 2, [red, red]), handles=np.array([True, False])
    )

    def gap(prompt: str) -> float:
        parsed = parse_prompt(prompt)
        prior, match = g._prior_for(parsed, True), g._knowledge_for(parsed)
        assert prior is None and match is not None and match.weight == pytest.approx(1.0)
        t = candidate_totals(parsed, feats, g._shape_prob(parsed), None, g.weights, knowledge=match)
        return float(t[0] - t[1])

    assert gap("the apple") == pytest.approx(-g.weights.handle)
    assert gap("the kettle") == pytest.approx(g.weights.handle)
    assert gap("the elephant") == pytest.approx(0.0)
    assert knowledge_handle_sign(g._knowledge_for(parse_prompt("the orange"))) == -1.0
    assert knowledge_handle_sign(g._knowledge_for(parse_prompt("the hammer"))) == 0.0  # its grip
