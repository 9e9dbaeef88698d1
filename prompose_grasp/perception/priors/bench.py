"""Measure the prior library's text matching: best family and score for known and unknown prompts.

    python -m prompose_grasp.perception.priors.bench [--json OUT.json]

Prints one row per prompt (expected family, best family, score, runner-up) and the gap between the lowest
in-library score and the highest out-of-library score, which is where `DEFAULT_MATCH_THRESHOLD` must lie.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

from prompose_grasp.perception.priors.library import DEFAULT_MATCH_THRESHOLD, PriorLibrary

#: Prompts a user might give for objects the library has, with the families that are a right answer.
#: The first block repeats or lightly varies descriptions; the second block is held out (words that appear in
#: no description), the honest test of retrieval.
IN_LIBRARY: tuple[tuple[str, str], ...] = (
    ("the yellow carton", "carton"),
    ("cardboard box", "carton"),
    ("cereal box", "box"),
    ("small red mug", "mug"),
    ("the white mug with a handle", "mug"),
    ("soda can", "can"),
    ("water bottle", "bottle"),
    ("salad bowl", "bowl"),
    ("paper cup", "cup"),
    ("the open laptop computer", "laptop"),
    ("digital camera", "camera"),
    ("tennis ball", "ball"),
    ("cardboard tube", "tube"),
    ("wooden pallet", "pallet"),
    ("flour sack", "sack"),
    ("padded envelope", "parcel"),
    ("dinner plate", "plate"),
    ("glass jar", "jar"),
    ("plastic crate", "crate"),
    ("hardcover book", "book"),
    # held out
    ("a brown moving carton", "carton"),
    ("amazon delivery box", "carton|box"),
    ("sugar box", "box"),
    ("pizza box", "box|carton"),
    ("espresso mug", "mug"),
    ("mustard bottle", "bottle"),
    ("bleach cleanser bottle", "bottle"),
    ("ketchup bottle", "bottle"),
    ("beer bottle", "bottle"),
    ("thermos flask", "bottle"),
    ("tomato soup can", "can"),
    ("coke can", "can"),
    ("energy drink can", "can"),
    ("ramen bowl", "bowl"),
    ("the blue bowl", "bowl"),
    ("plastic drinking cup", "cup"),
    ("wine glass", "cup"),
    ("gaming laptop", "laptop"),
    ("chromebook", "laptop"),
    ("camcorder", "camera"),
    ("golf ball", "ball"),
    ("volleyball", "ball"),
    ("poster roll", "tube"),
    ("a wooden EUR pallet", "pallet"),
    ("the sack of potatoes", "sack"),
    ("bag of cement", "sack"),
    ("padded mailer", "parcel"),
    ("porcelain plate", "plate"),
    ("cookie jar", "jar"),
    ("pickle jar", "jar"),
    ("milk crate", "crate"),
    ("cookbook", "book"),
)

#: Objects the library has no family for, whose shape none of the families resembles: none should reach
#: the threshold.
OUT_OF_LIBRARY: tuple[str, ...] = (
    "rubber duck",
    "stapler",
    "banana",
    "scissors",
    "power drill",
    "hammer",
    "screwdriver",
    "toothbrush",
    "remote control",
    "computer mouse",
    "sunglasses",
    "teddy bear",
    "shoe",
    "wrench",
    "potted plant",
    "pencil case",
    "headphones",
    "apple",
    "spoon",
    "keyboard",
    "toy car",
    "lego brick",
    "glove",
    "umbrella",
    "kitchen knife",
    "fork",
    "flashlight",
    "smartphone",
    "sponge",
    "candle",
)


def measure(library: PriorLibrary) -> dict[str, Any]:
    rows: list[dict[str, Any]] = []
    for prompt, expected in IN_LIBRARY:
        scores = library.match(prompt)
        rows.append(
            {
                "prompt": prompt,
                "expected": expected,
                "best": scores[0][0],
                "score": scores[0][1],
                "runner_up": scores[1][0],
                "runner_up_score": scores[1][1],
            }
        )
    out_rows: list[dict[str, Any]] = []
    for prompt in OUT_OF_LIBRARY:
        scores = library.match(prompt)
        out_rows.append({"prompt": prompt, "best": scores[0][0], "score": scores[0][1]})
    lowest_in = min(r["score"] for r in rows)
    highest_out = max(r["score"] for r in out_rows)
    return {
        "in_library": rows,
        "out_of_library": out_rows,
        "correct": sum(r["best"] in r["expected"].split("|") for r in rows),
        "lowest_in_library_score": lowest_in,
        "highest_out_of_library_score": highest_out,
        "threshold": library.threshold,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the measurements here")
    args = parser.parse_args()
    t0 = time.perf_counter()
    library = PriorLibrary(threshold=DEFAULT_MATCH_THRESHOLD)
    result = measure(library)
    print(f"{'prompt':36s} {'expected':13s} {'best':8s} {'score':>6s}  runner-up")
    for r in result["in_library"]:
        flag = "" if r["best"] in r["expected"].split("|") else "  <-- wrong"
        print(
            f"{r['prompt']:36s} {r['expected']:13s} {r['best']:8s} {r['score']:6.3f}  "
            f"{r['runner_up']} {r['runner_up_score']:.3f}{flag}"
        )
    print(f"\n{'out-of-library prompt':36s} {'best':8s} {'score':>6s}")
    for r in result["out_of_library"]:
        print(f"{r['prompt']:36s} {r['best']:8s} {r['score']:6.3f}")
    print(
        f"\ncorrect {result['correct']}/{len(result['in_library'])}; lowest in-library score "
        f"{result['lowest_in_library_score']:.3f}; highest out-of-library score "
        f"{result['highest_out_of_library_score']:.3f}; threshold {result['threshold']:.3f}; "
        f"{time.perf_counter() - t0:.1f} s"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
