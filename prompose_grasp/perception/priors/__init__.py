"""Canonical shape priors: text -> a mesh in the unit box with 5000 surface points (paper sections 3.3, 4.1).

The paper generates the prior with Hunyuan3D once per sequence. The embedded default here is a library of
parametric shape families retrieved by sentence similarity (`PriorLibrary`), with a superquadric fitted to
the first observation for words the library does not know (`fit_superquadric`), or a user CAD mesh
(`from_mesh`). docs/priors.md describes the choice, the families and their canonical frames.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.priors.families import FAMILIES, ShapeFamily
    from prompose_grasp.perception.priors.library import (
        DEFAULT_MATCH_THRESHOLD,
        PriorLibrary,
        core_phrase,
        head_noun,
        superquadric_prior,
    )
    from prompose_grasp.perception.priors.prior import (
        DEFAULT_N_POINTS,
        SYMMETRIES,
        ShapePrior,
        from_mesh,
        normalize_to_unit_box,
    )
    from prompose_grasp.perception.priors.superquadric import (
        SuperquadricFit,
        fit_superquadric,
        superquadric_inside_outside,
        superquadric_mesh,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.priors.families": (
            "FAMILIES",
            "ShapeFamily",
        ),
        "prompose_grasp.perception.priors.library": (
            "DEFAULT_MATCH_THRESHOLD",
            "PriorLibrary",
            "core_phrase",
            "head_noun",
            "superquadric_prior",
        ),
        "prompose_grasp.perception.priors.prior": (
            "DEFAULT_N_POINTS",
            "SYMMETRIES",
            "ShapePrior",
            "from_mesh",
            "normalize_to_unit_box",
        ),
        "prompose_grasp.perception.priors.superquadric": (
            "SuperquadricFit",
            "fit_superquadric",
            "superquadric_inside_outside",
            "superquadric_mesh",
        ),
    },
    submodules=(
        "families",
        "library",
        "prior",
        "superquadric",
    ),
)

__all__ = [
    "DEFAULT_MATCH_THRESHOLD",
    "DEFAULT_N_POINTS",
    "FAMILIES",
    "SYMMETRIES",
    "PriorLibrary",
    "ShapeFamily",
    "ShapePrior",
    "SuperquadricFit",
    "core_phrase",
    "fit_superquadric",
    "from_mesh",
    "head_noun",
    "normalize_to_unit_box",
    "superquadric_inside_outside",
    "superquadric_mesh",
    "superquadric_prior",
]
