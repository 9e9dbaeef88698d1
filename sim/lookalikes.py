"""The `lookalikes` bench-pick scenario: tabletop scenes with several products of one kind, as sold.

Each seed puts 3-4 products of one group (boxes, cans or bottles) and 1-2 products of the other groups on the
tabletop of `sim/scenes/tabletop_household.yaml` (same arm, cameras, bin and region as `real_meshes`),
randomly placed, and says one command of one of two kinds (`lookalike_kind`, even seeds the first):

- `implied`: "pick up the <product>" where the scene holds one such product and its look-alikes are other
  products of the group that differ from it in size or colour by construction (a 15 % extent or another
  colour): the name implies the difference ("the tuna can" is the flat one). The right answer is that one.
- `not_implied`: two copies of one product (same name, same size; one colour or two of the product's
  colours) and "pick up the <product>": the words do not tell them apart, so the right answer is the
  outcome `ambiguous`.

Objects are the simulator's procedural families (box, can, bottle) at the sizes of the `CATALOGUE`; the
scene prompt of each object (ground truth, never seen by the loop) is "<colour> <product>". Targets are
products the 85 mm parallel jaw can hold (`MAX_TARGET_GRIP_M`); wider ones (the tuna can, the coffee can, the
tissue box) are look-alikes only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

__all__ = [
    "CATALOGUE",
    "COLOURS",
    "GROUPS",
    "LOOKALIKE_KINDS",
    "MAX_TARGET_GRIP_M",
    "Product",
    "lookalike_scene",
    "tells_apart",
]

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
#: The tabletop region of `tabletop_household.yaml` (and of `real_meshes`), table frame [m].
REGION = {"centre_m": [-0.15, -0.05], "half_extents_m": [0.4, 0.3]}
LOOKALIKE_KINDS = ("implied", "not_implied")
#: Widest grip a target may need [m]: the 85 mm jaw less a centimetre of clearance.
MAX_TARGET_GRIP_M = 0.075
#: Look-alikes differ from the target by at least this fraction of an extent, or by colour.
MIN_SIZE_DIFFERENCE = 0.15

#: Colour names of the catalogue and their RGBA.
COLOURS: dict[str, list[float]] = {
    "red": [0.8, 0.12, 0.1, 1.0],
    "yellow": [0.88, 0.76, 0.1, 1.0],
    "white": [0.92, 0.92, 0.9, 1.0],
    "blue": [0.15, 0.3, 0.8, 1.0],
    "green": [0.1, 0.5, 0.2, 1.0],
    "brown": [0.45, 0.28, 0.12, 1.0],
    "silver": [0.7, 0.72, 0.75, 1.0],
    "orange": [0.9, 0.45, 0.1, 1.0],
    "black": [0.08, 0.08, 0.09, 1.0],
}


@dataclass(frozen=True)
class Product:
    """One catalogue row: a product a shopper names, its group (the head noun), the procedural family and its
    parameters [m] (box: width x height (up) x depth; can: radius, height; bottle: radius, height, neck and
    shoulder ratios), and the colours its packaging comes in."""

    name: str
    group: str
    family: str
    params: dict[str, float]
    colours: tuple[str, ...]

    @property
    def size_m(self) -> tuple[float, float, float]:
        """Canonical extents (x, y up, z) [m] of the built object."""
        p = self.params
        if self.family == "box":
            return (p["width_m"], p["height_m"], p["depth_m"])
        return (2 * p["radius_m"], p["height_m"], 2 * p["radius_m"])

    @property
    def grip_m(self) -> float:
        """The narrowest horizontal extent [m]: what a top-down parallel-jaw grasp must span."""
        s = self.size_m
        return min(s[0], s[2])


# The catalogue: sizes are general knowledge of the real products (typical packs: the YCB object set's
# sugar, gelatin, pudding and cracker boxes, tuna, soup, coffee and chips cans and mustard bottle; a 330 ml
# soda can, a 250 ml slim energy-drink can, a 0.5 l water bottle, a 0.75 l wine bottle, a 330 ml beer
# bottle), not measured here; colours are the usual packaging. Cylinders and oval bottles are round stand-ins
# (the family's shapes). Ground truth of the scenario: which objects the words fit is judged on these names,
# sizes and colours.
CATALOGUE: tuple[Product, ...] = (
    # name, group, family, parameters [m], colours
    Product("sugar box", "box", "box", {"width_m": 0.089, "height_m": 0.175, "depth_m": 0.038},
            ("white", "yellow")),
    Product("gelatin box", "box", "box", {"width_m": 0.085, "height_m": 0.073, "depth_m": 0.028}, ("red",)),
    Product("pudding box", "box", "box", {"width_m": 0.110, "height_m": 0.089, "depth_m": 0.035}, ("brown",)),
    Product("cracker box", "box", "box", {"width_m": 0.158, "height_m": 0.210, "depth_m": 0.060}, ("red",)),
    Product("cereal box", "box", "box", {"width_m": 0.200, "height_m": 0.300, "depth_m": 0.070},
            ("yellow", "orange", "blue")),
    Product("tea box", "box", "box", {"width_m": 0.130, "height_m": 0.075, "depth_m": 0.065},
            ("green", "red")),
    Product("tissue box", "box", "box", {"width_m": 0.240, "height_m": 0.090, "depth_m": 0.120},
            ("blue", "white")),
    Product("tuna can", "can", "can", {"radius_m": 0.0425, "height_m": 0.035}, ("silver",)),
    Product("soda can", "can", "can", {"radius_m": 0.033, "height_m": 0.122},
            ("red", "silver", "blue", "green")),
    Product("soup can", "can", "can", {"radius_m": 0.0335, "height_m": 0.101}, ("red",)),
    Product("coffee can", "can", "can", {"radius_m": 0.051, "height_m": 0.139}, ("blue",)),
    Product("chips can", "can", "can", {"radius_m": 0.0375, "height_m": 0.250}, ("red", "green")),
    Product("energy drink can", "can", "can", {"radius_m": 0.0265, "height_m": 0.134}, ("blue", "silver")),
    Product("tomato paste can", "can", "can", {"radius_m": 0.027, "height_m": 0.088}, ("red",)),
    Product("water bottle", "bottle", "bottle",
            {"radius_m": 0.033, "height_m": 0.210, "neck_ratio": 0.45, "shoulder_ratio": 0.70}, ("blue",)),
    Product("wine bottle", "bottle", "bottle",
            {"radius_m": 0.0375, "height_m": 0.300, "neck_ratio": 0.35, "shoulder_ratio": 0.62},
            ("green", "black")),
    Product("beer bottle", "bottle", "bottle",
            {"radius_m": 0.031, "height_m": 0.230, "neck_ratio": 0.40, "shoulder_ratio": 0.55},
            ("brown", "green")),
    Product("mustard bottle", "bottle", "bottle",
            {"radius_m": 0.033, "height_m": 0.190, "neck_ratio": 0.40, "shoulder_ratio": 0.72}, ("yellow",)),
    Product("ketchup bottle", "bottle", "bottle",
            {"radius_m": 0.034, "height_m": 0.200, "neck_ratio": 0.45, "shoulder_ratio": 0.72}, ("red",)),
    Product("olive oil bottle", "bottle", "bottle",
            {"radius_m": 0.032, "height_m": 0.270, "neck_ratio": 0.35, "shoulder_ratio": 0.65},
            ("green", "yellow")),
)  # fmt: skip
GROUPS: tuple[str, ...] = tuple(dict.fromkeys(p.group for p in CATALOGUE))


def tells_apart(a: Product, colour_a: str, b: Product, colour_b: str) -> bool:
    """Whether product `b` in `colour_b` differs from `a` in `colour_a` by construction: another name and
    an extent 15 % off, or another colour."""
    if a.name == b.name:
        return False  # the same product: its name does not tell the copies apart, whatever their colour
    size_off = any(abs(x - y) >= MIN_SIZE_DIFFERENCE * max(x, y) for x, y in zip(a.size_m, b.size_m))
    return size_off or colour_a != colour_b


def _pick(rng: np.random.Generator, seq):
    return seq[int(rng.integers(len(seq)))]


def _slug(name: str) -> str:
    return name.replace(" ", "_")


def lookalike_plan(seed: int) -> dict[str, Any]:
    """The objects and the command of one seed, by construction (no scene built).

    Returns {"command", "lookalike_kind", "said" (the product named), "target_object" (the scene object meant,
    None for not_implied), "fitting_objects" (every scene object the words fit), "objects": [{name, kind (the
    product), group, colour, size_m, prompt, family, params}] in scene order}.
    """
    rng = np.random.default_rng([int(seed), 20240])
    kind = LOOKALIKE_KINDS[int(seed) % 2]
    group = _pick(rng, GROUPS)
    members = [p for p in CATALOGUE if p.group == group]
    target = _pick(rng, [p for p in members if p.grip_m <= MAX_TARGET_GRIP_M])
    n_group = int(rng.integers(3, 5))  # 3 or 4 objects of the group
    chosen: list[tuple[Product, str]] = []
    if kind == "implied":
        colour = _pick(rng, target.colours)
        chosen.append((target, colour))
        pool = [p for p in members if p is not target]
        for k in rng.permutation(len(pool)):
            if len(chosen) == n_group:
                break
            p = pool[int(k)]
            ok = [c for c in p.colours if tells_apart(target, colour, p, c)]
            if ok:
                chosen.append((p, _pick(rng, ok)))
    else:
        if len(target.colours) > 1 and rng.random() < 0.5:
            i, j = rng.choice(len(target.colours), size=2, replace=False)
            colours = (target.colours[int(i)], target.colours[int(j)])
        else:
            c = _pick(rng, target.colours)
            colours = (c, c)
        chosen += [(target, colours[0]), (target, colours[1])]
        pool = [p for p in members if p is not target]
        for k in rng.permutation(len(pool))[: n_group - 2]:
            p = pool[int(k)]
            chosen.append((p, _pick(rng, p.colours)))
    others = [p for p in CATALOGUE if p.group != group]
    for k in rng.permutation(len(others))[: int(rng.integers(1, 3))]:
        p = others[int(k)]
        chosen.append((p, _pick(rng, p.colours)))

    objects = []
    counts: dict[str, int] = {}
    for p, _ in chosen:
        counts[p.name] = counts.get(p.name, 0) + 1
    seen: dict[str, int] = {}
    for p, colour in chosen:
        seen[p.name] = seen.get(p.name, 0) + 1
        name = _slug(p.name) if counts[p.name] == 1 else f"{_slug(p.name)}_{seen[p.name]}"
        objects.append(
            {
                "name": name,
                "kind": p.name,
                "group": p.group,
                "colour": colour,
                "size_m": [float(v) for v in p.size_m],
                "prompt": f"{colour} {p.name}",
                "family": p.family,
                "params": dict(p.params),
            }
        )
    order = rng.permutation(len(objects))
    objects = [objects[int(k)] for k in order]
    fitting = [o["name"] for o in objects if o["kind"] == target.name]
    return {
        "command": f"pick up the {target.name}",
        "lookalike_kind": kind,
        "said": target.name,
        "target_object": fitting[0] if kind == "implied" else None,
        "fitting_objects": fitting,
        "objects": objects,
    }


def lookalike_scene(seed: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """(scene document, plan) of one seed: the tabletop of `tabletop_household.yaml` with the plan's objects
    (`lookalike_plan`) in place of its own, placed at random in its region."""
    plan = lookalike_plan(seed)
    doc = yaml.safe_load((SCENES_DIR / "tabletop_household.yaml").read_text())
    doc["objects"] = [
        {
            "name": o["name"],
            "prompt": o["prompt"],
            "mesh": {"family": o["family"], "params": o["params"]},
            "rgba": COLOURS[o["colour"]],
            "place": {"support": "table", "region": REGION},
        }
        for o in plan["objects"]
    ]
    doc["name"] = "tabletop_lookalikes"
    return doc, plan
