"""ProM-Pose perception: RGB-D frames + a prompt -> the metric 9-DoF box and scaled prior mesh of the object.

- `ProMPose` (`perception.estimator`): the facade, `ProMPose.default().estimate(frame, prompt)` / `.track`.
- `prompose_grasp.perception.grounding`: text -> mask (`Grounder`, the DINO + SAM 2 adapter).
- `prompose_grasp.perception.fit`: the test-time L_geo fit of the prior (`fit_pose`).
- `prompose_grasp.perception.tracker`: the sliding-window tracker behind `ProMPose.track`.

- `prompose_grasp.perception.text`: sentence / token text encoders (`MiniLMTextEncoder` embedded default,
  `BertTextEncoder` adapter) and cosine `similarity`.
- `prompose_grasp.perception.priors`: text -> canonical unit-box shape prior (`PriorLibrary`,
  `fit_superquadric`, `from_mesh`).

Nothing heavy loads at import (the names below resolve on first access); the MiniLM weights load on the
first text that neither the shipped vocabulary embeddings nor the user cache hold (`perception.text`).
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.estimator import Estimate, EstimatorConfig, ProMPose
    from prompose_grasp.perception.fit import FitConfig, FitResult, fit_pose
    from prompose_grasp.perception.grounding import (
        Candidate,
        Grounder,
        GroundingConfig,
        GroundingDinoSam2Grounder,
        GroundingResult,
        SupportPlane,
    )
    from prompose_grasp.perception.priors import (
        PriorLibrary,
        ShapePrior,
        SuperquadricFit,
        fit_superquadric,
        from_mesh,
    )
    from prompose_grasp.perception.text import (
        BertTextEncoder,
        MiniLMTextEncoder,
        TextEncoder,
        default_text_encoder,
        similarity,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.estimator": (
            "Estimate",
            "EstimatorConfig",
            "ProMPose",
        ),
        "prompose_grasp.perception.fit": (
            "FitConfig",
            "FitResult",
            "fit_pose",
        ),
        "prompose_grasp.perception.grounding": (
            "Candidate",
            "Grounder",
            "GroundingConfig",
            "GroundingDinoSam2Grounder",
            "GroundingResult",
            "SupportPlane",
        ),
        "prompose_grasp.perception.priors": (
            "PriorLibrary",
            "ShapePrior",
            "SuperquadricFit",
            "fit_superquadric",
            "from_mesh",
        ),
        "prompose_grasp.perception.text": (
            "BertTextEncoder",
            "MiniLMTextEncoder",
            "TextEncoder",
            "default_text_encoder",
            "similarity",
        ),
    },
    submodules=(
        "dataset",
        "estimator",
        "fit",
        "frames_io",
        "grounding",
        "knowledge",
        "network",
        "overlay",
        "priors",
        "text",
        "tracker",
        "train",
    ),
)

__all__ = [
    "BertTextEncoder",
    "Candidate",
    "Estimate",
    "EstimatorConfig",
    "FitConfig",
    "FitResult",
    "Grounder",
    "GroundingConfig",
    "GroundingDinoSam2Grounder",
    "GroundingResult",
    "MiniLMTextEncoder",
    "PriorLibrary",
    "ProMPose",
    "ShapePrior",
    "SuperquadricFit",
    "SupportPlane",
    "TextEncoder",
    "default_text_encoder",
    "fit_pose",
    "fit_superquadric",
    "from_mesh",
    "similarity",
]
