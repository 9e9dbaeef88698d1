"""Outcome accounting of the pick benchmark (`sim.bench_pick`): which objects the words fit, how a row counts.

Ground truth only, after the run: nothing here is seen by the loop. A row is judged on

- the loop's own outcome reason (`PickOutcome.reason`: "success", "not_found", ..., and where the library
  has them "ambiguous": several objects fit the words and the run refused, and "wrong_object": after lifting,
  the loop found it held another object than the one named and put it back);
- the ground-truth success of the episode (`sim.pick.run_episode`: the named object lifted / at the place);
- the objects the words fit by construction (`fitting_objects`, from the scenario's own catalogue: name or
  kind, colour, size), and the objects that rose (`lifted_objects`) or ended at the place target
  (`placed_objects`).

Accounted reasons (`judge`): "success"; "wrong_object_success" (the loop reported success, ground truth shows
another scene object lifted or placed and not the named one); "false_success" (the loop reported success,
nothing the words fit was lifted or placed, and no other object either); "ambiguous" with the judgement
"correct" (at least two scene objects fit the words, the named attribute does not tell them apart) or
"wrong" (a refusal where the words were clear); "wrong_object" (the loop's typed, safe failure) and every
other loop reason as it is; "crash:<Exception>" from the bench.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    "COLOUR_WORDS",
    "bare_name",
    "describe_prompt",
    "fitting_objects",
    "judge",
    "object_phrase",
    "tally",
    "tally_by_kind",
    "wilson_interval",
]

#: Colour words a prompt or a command may carry (the scenarios' palettes and common others).
COLOUR_WORDS = frozenset(
    "red green blue yellow orange purple white black brown grey gray silver pink beige gold".split()
)
#: Size words and which end of the fitting objects they keep (+1 the largest, -1 the smallest); "tall" /
#: "short" compare heights, the others volumes.
SIZE_WORDS: Mapping[str, int] = {
    **dict.fromkeys(("big", "bigger", "biggest", "large", "larger", "largest", "huge"), +1),
    **dict.fromkeys(("small", "smaller", "smallest", "little", "tiny", "mini"), -1),
    **dict.fromkeys(("tall", "taller", "tallest"), +1),
    **dict.fromkeys(("short", "shorter", "shortest"), -1),
}
_HEIGHT_WORDS = frozenset(("tall", "taller", "tallest", "short", "shorter", "shortest"))
#: Words of a command that name no object (verbs, articles, politeness).
_STOP_WORDS = frozenset(
    "pick pickup up lift grab take get fetch put place move hand give me please the a an that this one "
    "it and of".split()
)
#: Objects whose size is within this fraction of the extreme one count as the same size for a size word.
_SAME_SIZE = 0.15

#: Reasons that are a wrong pick: a success on another object, or the loop's own typed catch of one.
WRONG_PICK_REASONS = ("wrong_object_success", "wrong_object")


def _words(text: str) -> list[str]:
    return re.findall(r"[a-z]+", text.lower())


def describe_prompt(prompt: str) -> tuple[str | None, str]:
    """(colour word or None, kind) of a scene prompt: "red soda can" -> ("red", "soda can"); "tea box" ->
    (None, "tea box"). The colour is the prompt's first colour word; the kind is the rest."""
    words = _words(prompt)
    colour = next((w for w in words if w in COLOUR_WORDS), None)
    kind = " ".join(w for w in words if w != colour)
    return colour, kind


def bare_name(prompt: str) -> str:
    """The prompt without its colour words ("red banana" -> "banana", "blue paper cup" -> "paper cup"):
    what `--prompts name` says."""
    return " ".join(w for w in prompt.split() if w.lower() not in COLOUR_WORDS)


def object_phrase(command_text: str) -> str:
    """The command up to its place preposition, lower case ("put the can in the bin" -> "put the can")."""
    text = " " + command_text.lower().replace(",", " ") + " "
    for prep in (" on top of ", " onto ", " into ", " inside ", " in ", " on ", " to "):
        text = text.split(prep)[0]
    return text.strip()


def _object_words(command: str) -> list[str]:
    return [w for w in _words(object_phrase(command)) if w not in _STOP_WORDS]


def fitting_objects(command: str, objects: Sequence[Mapping[str, Any]]) -> list[str]:
    """Names of the scene objects the command's object phrase fits, by construction (ground truth).

    `objects`: {name, kind, colour, size_m (or None)} per scene object (`kind`: the catalogue name, "soda
    can"; missing: derived from `prompt` by `describe_prompt`). An object fits when the phrase's object words
    (without colour and size words) are all words of its kind and include the kind's head noun ("the can" and
    "the soda can" fit a soda can, "the tuna can" does not), every colour word named is its colour, and a
    size word ("small", "large", "tall") keeps only the fitting objects within 15 % of the extreme size.
    """
    words = _object_words(command)
    colours = {w for w in words if w in COLOUR_WORDS}
    size_words = [w for w in words if w in SIZE_WORDS]
    nouns = {w for w in words if w not in COLOUR_WORDS and w not in SIZE_WORDS}
    if not nouns:
        return []
    fit = []
    for o in objects:
        colour, kind = o.get("colour"), o.get("kind")
        if kind is None:
            colour, kind = describe_prompt(str(o.get("prompt") or o["name"]))
        kind_words = _words(kind)
        if not kind_words or kind_words[-1] not in nouns or not nouns <= set(kind_words):
            continue
        if colours and (colour is None or colour.lower() not in colours):
            continue
        fit.append(o)
    for w in size_words:
        sized = [o for o in fit if o.get("size_m") is not None]
        if len(sized) < len(fit) or len(fit) < 2:
            break  # a size not known for every candidate (or nothing to choose from): not narrowed

        def measure(o: Mapping[str, Any], w: str = w) -> float:
            s = [float(v) for v in o["size_m"]]
            return s[1] if w in _HEIGHT_WORDS else math.prod(s)

        extreme = max(fit, key=measure) if SIZE_WORDS[w] > 0 else min(fit, key=measure)
        m = measure(extreme)
        fit = [o for o in fit if abs(measure(o) - m) <= _SAME_SIZE * m]
    return [str(o["name"]) for o in fit]


def judge(
    loop_reason: str,
    gt_success: bool,
    fitting: Sequence[str],
    lifted: Sequence[str] = (),
    placed: Sequence[str] | None = None,
    place: bool = False,
) -> dict[str, Any]:
    """How one episode counts: {"reason", "success", "ambiguous" ("correct" | "wrong" | None),
    "wrong_objects" (the other objects lifted / placed in a wrong-object success)}.

    Args:
        loop_reason: the loop's `PickOutcome.reason` (strings, not the library's list: "ambiguous" and
            "wrong_object" are recognised whether or not the library has them yet).
        gt_success: the episode's ground-truth success (`run_episode`'s `success`).
        fitting: the scene objects the words fit by construction (`fitting_objects`).
        lifted: objects whose centre rose >= `sim.pick.MIN_LIFT_M` (`evaluation.lifted_objects`).
        placed: objects that ended inside the place target (`evaluation.placed_objects`); place commands.
        place: the command was a place (the wrong object is the one placed, not the one lifted).
    """
    ambiguous = None
    others: list[str] = []
    if loop_reason == "success":
        if gt_success:
            reason = "success"
        else:
            moved_there = list(placed) if (place and placed is not None) else list(lifted)
            others = [n for n in moved_there if n not in fitting]
            reason = "wrong_object_success" if others else "false_success"
    elif loop_reason == "ambiguous":
        reason = "ambiguous"
        ambiguous = "correct" if len(fitting) >= 2 else "wrong"
    else:
        reason = loop_reason
    return {
        "reason": reason,
        "success": reason == "success",
        "ambiguous": ambiguous,
        "wrong_objects": others,
    }


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % for the default z); (0, 1) when n = 0."""
    if n <= 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def _rate(k: int, n: int) -> dict[str, Any]:
    lo, hi = wilson_interval(k, n)
    return {"count": k, "rate": (k / n) if n else None, "wilson95": [lo, hi]}


def tally(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The counts of the report from accounted rows (each with "reason", "success", optional "ambiguous")."""
    n = len(rows)
    reasons = Counter(str(r["reason"]) for r in rows if not r["success"])
    amb = [r for r in rows if r["reason"] == "ambiguous"]
    n_correct = sum(r.get("ambiguous") == "correct" for r in amb)
    wrong_pick = sum(reasons[k] for k in WRONG_PICK_REASONS)
    return {
        "wrong_object_success": reasons["wrong_object_success"],
        "false_success": reasons["false_success"],
        "ambiguous": {"total": len(amb), "correct": n_correct, "wrong": len(amb) - n_correct},
        "wrong_object": reasons["wrong_object"],
        "wrong_pick": wrong_pick,
        "wrong_pick_rate": (wrong_pick / n) if n else None,
        "reasons": dict(sorted(reasons.items())),
        "other_failures": {
            k: v
            for k, v in sorted(reasons.items())
            if k not in ("wrong_object_success", "false_success", "ambiguous", "wrong_object")
        },
    }


def tally_by_kind(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Per `lookalike_kind` (rows without one are left out; {} when none has one).

    `implied` (the name tells the object apart): `top1` = successes; `not_implied` (two objects the words do
    not tell apart): `ambiguous` = refusals judged correct, `picked_one` = successes on one of the look-alikes
    without asking. Both: `correct` (implied: top-1; not_implied: ambiguous correct), `wrong_pick`
    (wrong_object_success + wrong_object) with Wilson 95 % intervals, and the reasons."""
    out: dict[str, Any] = {}
    for kind in ("implied", "not_implied"):
        sub = [r for r in rows if r.get("lookalike_kind") == kind]
        if not sub:
            continue
        n = len(sub)
        succ = sum(bool(r["success"]) for r in sub)
        amb_ok = sum(r["reason"] == "ambiguous" and r.get("ambiguous") == "correct" for r in sub)
        amb_all = sum(r["reason"] == "ambiguous" for r in sub)
        wrong = sum(r["reason"] in WRONG_PICK_REASONS for r in sub)
        entry: dict[str, Any] = {"episodes": n}
        if kind == "implied":
            entry["top1"] = _rate(succ, n)
            entry["ambiguous"] = amb_all
            entry["correct"] = _rate(succ, n)
        else:
            entry["ambiguous"] = _rate(amb_ok, n)
            entry["picked_one"] = succ
            entry["correct"] = _rate(amb_ok, n)
        entry["wrong_pick"] = _rate(wrong, n)
        entry["reasons"] = dict(sorted(Counter(str(r["reason"]) for r in sub).items()))
        out[kind] = entry
    return out
