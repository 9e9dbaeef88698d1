"""Objects described the way a person would, for the loop's messages: "the red box on the left, 17 cm tall".

Everything comes from what the loop knows of an object: its estimated box (camera frame, and the base frame
through the frame's `T_base_cam`) and the grounder's measured `attributes` (the colour word). Left and right
are the camera's (its x axis: image x), in front and behind its distance; the size is the box's height
along base +z, or its largest extent for a flat thing.

```
describe_contenders("the box", [red, blue], T_base_cam)
# "2 objects fit 'the box': the red box on the left, 17 cm tall; the blue box on the right, 10 cm tall.
#  Say which one (e.g. "the red box")."
```
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from prompose_grasp.perception.grounding.describe import PALETTE, colour_names
from prompose_grasp.perception.grounding.language import parse_prompt
from prompose_grasp.pipeline.seams import ObjectEstimate

__all__ = [
    "colour_share",
    "describe_contenders",
    "object_noun",
    "phrase",
    "positions",
    "prompt_colour",
    "size_words",
]

_ARTICLE = re.compile(r"^(?:(?:all|both|every)\s+)?(?:(?:the|an|a|this|that|these|those|some)\s+)?")
#: Where a phrase starts saying where the object is, not what it is ("the mug left of the bowl").
_RELATION = re.compile(
    r"\s+(?:left|right|next|in front|behind|near|beside|by|on|in|inside|under|below|above|with|from|at|"
    r"between|of|that|which)\b.*$"
)
_SIZE_WORDS = frozenset(
    ("small", "little", "tiny", "big", "large", "medium", "tall", "short", "long", "huge")
)
_COLOUR_ALIASES = {"gray": "grey"}
_ORDINALS = ("first", "second", "third", "fourth", "fifth", "sixth", "seventh", "eighth", "ninth", "tenth")
#: Objects whose centres lie closer than this along both the view's width and its depth get no position
#: word: "on the left" of a neighbour 1 cm away tells a person nothing (estimates are ~1 cm off) [m].
_SAME_SPOT_M = 0.02
#: A thing at least this fraction of its largest extent tall is described by its height ("17 cm tall"),
#: a flatter one by its largest extent ("25 cm across": a plate, a laptop) [-].
_TALL_FRACTION = 0.5


def _head(prompt: str) -> list[str]:
    """The words of the prompt that say what the object is: no article, no relation to other things."""
    text = " ".join(re.sub(r"[^\w\s'-]", " ", prompt.lower()).split())
    text = _RELATION.sub("", _ARTICLE.sub("", text, count=1))
    return [_COLOUR_ALIASES.get(w, w) for w in text.split()]


def object_noun(prompt: str) -> str:
    """The kind the prompt names, without article, colour, size or relation (`grounding.parse_prompt`'s
    noun): "the red soda can left of the bowl" -> "soda can"; "object" when nothing is left ("the red
    one")."""
    parsed = parse_prompt(prompt)
    return "object" if parsed.generic else parsed.noun


def prompt_colour(prompt: str) -> str | None:
    """The one palette colour the prompt's object words name ("the green bottle" -> "green", "the navy
    cup" -> "blue"), or None (no colour, or several: "the red and white box"). A colour after a relation
    names another thing ("the mug next to the red bowl")."""
    colours = parse_prompt(prompt).colours
    return colours[0] if len(colours) == 1 else None


def colour_share(
    rgb: np.ndarray, mask: np.ndarray | None, colour: str, depth_m: np.ndarray | None = None
) -> float:
    """Share in [0, 1] of the `mask` pixels of (H, W, 3) uint8 `rgb` that the grounder's palette names
    `colour` (`grounding.describe.colour_names`); pixels without a depth reading in `depth_m` (the robot's
    own, filtered out) do not count. NaN when it cannot be measured (no mask, another shape, no pixel)."""
    if mask is None or colour not in PALETTE:
        return float("nan")
    m = np.asarray(mask, dtype=bool)
    if m.shape != np.asarray(rgb).shape[:2]:
        return float("nan")
    if depth_m is not None and np.asarray(depth_m).shape == m.shape:
        m = m & (np.nan_to_num(np.asarray(depth_m, dtype=np.float64)) > 0)
    if not m.any():
        return float("nan")
    names = colour_names(np.asarray(rgb)[m])
    return float(np.mean(names == PALETTE.index(colour)))


def positions(centres_cam: np.ndarray) -> list[str]:
    """Where each of (n, 3) camera-frame centres [m] lies among the others, as seen by the camera: along the
    view's width ("on the left", "in the middle", "on the right", "second from the left") when they spread
    more across the view than in depth, else by distance ("in front", ..., "behind"). Empty words when n < 2
    or all lie within `_SAME_SPOT_M` of each other."""
    c = np.asarray(centres_cam, dtype=np.float64).reshape(-1, 3)
    n = len(c)
    if n < 2:
        return [""] * n
    z = c[:, 2]
    # Across the view: the bearing x / z, in metres at the mean depth (a far object's x shrinks in the image).
    lateral = c[:, 0] / z * float(np.mean(z)) if np.all(z > 0) else c[:, 0]
    distance = np.linalg.norm(c, axis=1)
    across, deep = float(np.ptp(lateral)), float(np.ptp(distance))
    if max(across, deep) < _SAME_SPOT_M:
        return [""] * n
    if across >= deep:
        key, first, last, side = lateral, "on the left", "on the right", "left"
    else:
        key, first, last, side = distance, "in front", "behind", "front"
    words = [""] * n
    for rank, i in enumerate(np.argsort(key, kind="stable")):
        if rank == 0:
            words[i] = first
        elif rank == n - 1:
            words[i] = last
        elif n == 3:
            words[i] = "in the middle"
        else:
            ordinal = _ORDINALS[rank] if rank < len(_ORDINALS) else f"number {rank + 1}"
            words[i] = f"{ordinal} from the {side}"
    return words


def size_words(est: ObjectEstimate, T_base_cam: np.ndarray) -> str:
    """ "17 cm tall" (the box's extent along base +z) or, for a flat thing, "25 cm across" (its largest
    extent)."""
    R_base = np.asarray(T_base_cam, dtype=np.float64)[:3, :3] @ np.asarray(est.pose.R, dtype=np.float64)
    size = np.asarray(est.pose.size, dtype=np.float64)
    height = float(np.abs(R_base[2, :]) @ size)
    largest = float(np.max(size))
    if height >= _TALL_FRACTION * largest:
        return f"{100.0 * height:.0f} cm tall"
    return f"{100.0 * largest:.0f} cm across"


def _colour(est: ObjectEstimate) -> str:
    attributes = getattr(est, "attributes", None)
    return str(getattr(attributes, "colour_name", "") or "")


def phrase(est: ObjectEstimate, noun: str, position: str = "", T_base_cam: np.ndarray | None = None) -> str:
    """ "the red box on the left, 17 cm tall": the colour word when the grounder measured one, the `noun`,
    the `position` word and, with `T_base_cam`, the size."""
    words = " ".join(w for w in ("the", _colour(est), noun, position) if w)
    return words if T_base_cam is None else f"{words}, {size_words(est, T_base_cam)}"


def describe_contenders(
    prompt: str, estimates: Sequence[ObjectEstimate], T_base_cam: np.ndarray, count: int | None = None
) -> str:
    """The answer to an ambiguous prompt: how many objects fit it, each described (colour, kind, where it is
    among the others, size), and a narrower phrase to say. `estimates`: the contenders of one frame, best
    first, camera frame of `T_base_cam`; `count`: how many fit in all when not every one was estimated."""
    noun = object_noun(prompt)
    where = positions(np.array([np.asarray(e.pose.t, dtype=np.float64) for e in estimates]).reshape(-1, 3))
    parts = [phrase(e, noun, w, T_base_cam) for e, w in zip(estimates, where)]
    total = max(int(count or 0), len(estimates))
    if total > len(estimates):
        parts.append(f"and {total - len(estimates)} more")
    text = f"{total} objects fit {prompt!r}: " + "; ".join(parts) + "."
    if estimates:
        colours = [_colour(e) for e in estimates]
        best_colour = colours[0]
        if best_colour and colours.count(best_colour) == 1:  # the colour alone tells it apart
            example = f"the {best_colour} {noun}"
        else:
            example = phrase(estimates[0], noun, where[0])
        text += f' Say which one (e.g. "{example}").'
    return text
