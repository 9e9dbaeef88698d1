"""Prompts are read in English: full-width forms normalised (NFKC), accents dropped, and a prompt without a
Latin letter refused with that reason (not as "blank")."""

from __future__ import annotations

import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.grounding.language import check_prompt, fold_text, parse_prompt


@pytest.mark.parametrize(
    ("text", "folded"),
    [
        ("ｔｈｅ　ｒｅｄ　ｍｕｇ", "the red mug"),  # full-width letters and the ideographic space
        ("ＭＵＧ１２", "MUG12"),
        ("café crème", "cafe creme"),
        ("ﬁle box", "file box"),  # the fi ligature
        ("the red mug", "the red mug"),  # ASCII is left as it is
    ],
)
def test_fold_text(text, folded):
    assert fold_text(text) == folded


def test_full_width_prompts_parse_as_their_ascii_form():
    assert parse_prompt("ｔｈｅ　ｒｅｄ　ｍｕｇ") == parse_prompt("the red mug")
    assert check_prompt("  ｒｅｄ ｍｕｇ ") == "red mug"


@pytest.mark.parametrize(
    "prompt", ["赤いマグカップ", "红色杯子", "كوب أحمر", "🥫", "красная кружка", "１２３", "!!!"]
)
def test_prompts_without_a_latin_letter_are_refused_with_that_reason(prompt):
    with pytest.raises(InvalidInputError, match="has no word in Latin letters") as err:
        parse_prompt(prompt)
    assert "blank" not in str(err.value)


@pytest.mark.parametrize(
    ("prompt", "why"), [("", "empty"), ("  \t", "empty"), (None, "must be a str"), (5, "str")]
)
def test_blank_and_non_text_prompts_are_refused(prompt, why):
    with pytest.raises(InvalidInputError, match=why):
        check_prompt(prompt)


def test_a_prompt_mixing_scripts_keeps_its_latin_words():
    assert parse_prompt("the 赤い mug").noun == "mug"
