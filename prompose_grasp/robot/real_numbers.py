"""Strict numeric arguments for motion commands: real numbers only, nothing coerced on the way.

`np.asarray(x, dtype=np.float64)` accepts far more than a motion command should: it parses the string "0.5",
turns True into 1.0, drops the imaginary part of a complex number (with a warning) and reads a bool mask as
0/1. A command built from any of these is a bug upstream, so these helpers refuse them with an
`InvalidInputError` that says what is accepted:

- arrays: a numpy array of a real float or integer dtype, or a (nested) list / tuple of Python or numpy ints
  and floats. Integer values are converted to float64 exactly (joint and pose values are far below 2**53).
- numbers: a Python int or float or a numpy integer or floating scalar (not a bool, not an array).

Whether the values are finite and within limits is for the caller to check (an unsafe value is an
`UnsafeCommandError`, a wrong type an `InvalidInputError`).
"""

from __future__ import annotations

from typing import TypeGuard

import numpy as np

from prompose_grasp.errors import InvalidInputError

__all__ = ["ACCEPTED_ARRAYS", "ACCEPTED_NUMBERS", "real_array", "real_number"]

#: What `real_array` accepts, for error messages.
ACCEPTED_ARRAYS = (
    "a numpy float or int array, or a list / tuple of Python floats or ints; not bool, complex, str or None"
)
#: What `real_number` accepts, for error messages.
ACCEPTED_NUMBERS = "a real number (Python or numpy int or float; not bool, complex, str, array or None)"

_REAL_KINDS = "fiu"  # numpy dtype kinds: floating, signed and unsigned integer


def _describe(value: object) -> str:
    if isinstance(value, np.ndarray):
        return f"a {value.dtype} array of shape {value.shape}"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 60 else text[:57] + '...'}"


def _is_real_scalar(value: object) -> TypeGuard[int | float | np.integer | np.floating]:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


def _leaves_are_real(value: list | tuple) -> bool:
    """Every leaf of a nested list / tuple is a real int or float (bools, strings, None, ... are not)."""
    for item in value:
        if isinstance(item, (list, tuple)):
            if not _leaves_are_real(item):
                return False
        elif isinstance(item, np.ndarray):
            if item.dtype.kind not in _REAL_KINDS:
                return False
        elif not _is_real_scalar(item):
            return False
    return True


def _shape_text(shape: tuple[int | None, ...]) -> str:
    dims = ["N" if n is None else str(n) for n in shape]
    return f"({dims[0]},)" if len(dims) == 1 else f"({', '.join(dims)})"


def real_array(value: object, name: str, shape: tuple[int | None, ...] | None = None) -> np.ndarray:
    """A float64 copy of `value` if it holds real numbers (see the module docstring) of `shape`.

    Args:
        value: the argument.
        name: how the argument is named in the error message (e.g. "move_joints: q_target").
        shape: the required shape, None entries for any length (e.g. (None, 6)); None for any shape.
    Raises:
        InvalidInputError: the type, dtype or shape is not accepted; the message says what is.
    """
    want = "real numbers" if shape is None else f"{_shape_text(shape)} real numbers"
    if isinstance(value, np.ndarray):
        arr = value
    elif isinstance(value, (list, tuple)) and _leaves_are_real(value):
        try:
            arr = np.asarray(value)
        except ValueError:  # a ragged nesting
            raise InvalidInputError(
                f"{name} must be {want} ({ACCEPTED_ARRAYS}); got a ragged {type(value).__name__}"
            ) from None
    else:
        raise InvalidInputError(f"{name} must be {want} ({ACCEPTED_ARRAYS}); got {_describe(value)}")
    if arr.dtype.kind not in _REAL_KINDS:  # bool, complex, str, object, datetime ...
        raise InvalidInputError(f"{name} must be {want} ({ACCEPTED_ARRAYS}); got {_describe(arr)}")
    if shape is not None and (
        arr.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, arr.shape))
    ):
        raise InvalidInputError(f"{name} must have shape {_shape_text(shape)}; got {arr.shape}")
    return np.array(arr, dtype=np.float64)  # a plain ndarray copy (not a subclass such as np.matrix)


def real_number(value: object, name: str) -> float:
    """`value` as a float if it is a real number (see the module docstring); InvalidInputError otherwise."""
    if not _is_real_scalar(value):
        raise InvalidInputError(f"{name} must be {ACCEPTED_NUMBERS}; got {_describe(value)}")
    try:
        return float(value)
    except OverflowError:  # a Python int beyond the float range
        raise InvalidInputError(f"{name} must be {ACCEPTED_NUMBERS} within the float range") from None
