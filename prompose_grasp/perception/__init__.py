"""ProM-Pose perception: text encoding and canonical shape priors (more modules join as they land).

- `prompose_grasp.perception.text`: sentence / token text encoders (`MiniLMTextEncoder` embedded default,
  `BertTextEncoder` adapter) and cosine `similarity`.
- `prompose_grasp.perception.priors`: text -> canonical unit-box shape prior (`PriorLibrary`,
  `fit_superquadric`, `from_mesh`).

Nothing heavy loads at import: the MiniLM weights load on the first `default_text_encoder()` call.
"""

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

__all__ = [
    "BertTextEncoder",
    "MiniLMTextEncoder",
    "PriorLibrary",
    "ShapePrior",
    "SuperquadricFit",
    "TextEncoder",
    "default_text_encoder",
    "fit_superquadric",
    "from_mesh",
    "similarity",
]
