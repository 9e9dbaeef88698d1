"""Language grounding (text -> mask): the first stage of ProM-Pose (the paper uses Grounded-SAM 2).

Two grounders share one call, `.ground(rgb, depth_m, intrinsics, prompt) -> GroundingResult`:

- the embedded default (`Grounder`, `ground`): finds the support plane (RANSAC), clusters the points above
  it into object candidates (3D proximity and colour edges), measures each candidate's colour, size and
  shape family and scores it against the prompt with the offline MiniLM sentence embedding plus explicit
  handling of colour, size and spatial words;
- the adapter `GroundingDinoSam2Grounder`: Grounding DINO boxes + SAM 2 masks through `transformers`
  (extra `hub`), loaded from a local weights folder.

docs/grounding.md describes the method, its thresholds and its measured speed and accuracy.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.grounding.describe import (
        HEIGHT_BINS,
        PALETTE,
        SHAPE_FAMILIES,
        SIZE_CLASSES,
    )
    from prompose_grasp.perception.grounding.dino_sam import GroundingDinoSam2Grounder
    from prompose_grasp.perception.grounding.grounder import Grounder, ground, validate_frame
    from prompose_grasp.perception.grounding.language import ParsedPrompt, parse_prompt
    from prompose_grasp.perception.grounding.score import NounPrior, ScoringWeights
    from prompose_grasp.perception.grounding.types import (
        Candidate,
        CandidateAttributes,
        GroundingConfig,
        GroundingResult,
        GroundingTiming,
        SupportPlane,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.grounding.describe": (
            "HEIGHT_BINS",
            "PALETTE",
            "SHAPE_FAMILIES",
            "SIZE_CLASSES",
        ),
        "prompose_grasp.perception.grounding.dino_sam": ("GroundingDinoSam2Grounder",),
        "prompose_grasp.perception.grounding.grounder": (
            "Grounder",
            "ground",
            "validate_frame",
        ),
        "prompose_grasp.perception.grounding.language": (
            "ParsedPrompt",
            "parse_prompt",
        ),
        "prompose_grasp.perception.grounding.score": (
            "NounPrior",
            "ScoringWeights",
        ),
        "prompose_grasp.perception.grounding.types": (
            "Candidate",
            "CandidateAttributes",
            "GroundingConfig",
            "GroundingResult",
            "GroundingTiming",
            "SupportPlane",
        ),
    },
    submodules=(
        "confidence",
        "describe",
        "dino_sam",
        "grounder",
        "language",
        "plane",
        "score",
        "segment",
        "types",
    ),
)

__all__ = [
    "HEIGHT_BINS",
    "PALETTE",
    "SHAPE_FAMILIES",
    "SIZE_CLASSES",
    "Candidate",
    "CandidateAttributes",
    "Grounder",
    "GroundingConfig",
    "GroundingDinoSam2Grounder",
    "GroundingResult",
    "GroundingTiming",
    "NounPrior",
    "ParsedPrompt",
    "ScoringWeights",
    "SupportPlane",
    "ground",
    "parse_prompt",
    "validate_frame",
]
