"""Rotation helpers in torch: the continuous 6-D representation and a numerically safe geodesic angle."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["axis_angle_between", "geodesic_angle", "rotation_6d_to_matrix"]

#: Added under square roots so their gradient stays finite at zero (an angle of 1e-6 rad at identity).
_SQRT_EPS = 1e-12


def rotation_6d_to_matrix(x: Tensor) -> Tensor:
    """(..., 6) -> (..., 3, 3) rotation by Gram-Schmidt (Zhou et al. 2019).

    The 6 numbers are the first two columns (a1, a2); b1 = a1/|a1|, b2 = normalised a2 - (b1.a2) b1,
    b3 = b1 x b2. Continuous everywhere except where a1 and a2 are parallel.
    """
    a1, a2 = x[..., 0:3], x[..., 3:6]
    b1 = a1 / torch.sqrt((a1 * a1).sum(-1, keepdim=True) + _SQRT_EPS)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / torch.sqrt((a2 * a2).sum(-1, keepdim=True) + _SQRT_EPS)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def geodesic_angle(R_a: Tensor, R_b: Tensor) -> Tensor:
    """|log(R_a^T R_b)|: the rotation angle between (..., 3, 3) rotations [rad] in [0, pi].

    atan2(sin, cos) with sin from the skew part and cos from the trace is accurate at 0 and at pi, where
    acos of the trace alone loses precision and has an infinite derivative.
    """
    M = R_a.transpose(-1, -2) @ R_b
    cos = (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1.0) * 0.5
    skew = torch.stack(
        [M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], dim=-1
    )
    sin = 0.5 * torch.sqrt((skew * skew).sum(-1) + _SQRT_EPS)
    return torch.atan2(sin, cos)


def axis_angle_between(a: Tensor, b: Tensor) -> Tensor:
    """Angle between (..., 3) unit vectors [rad] in [0, pi], safe at 0 and pi (atan2 of |a x b| and a.b)."""
    c = torch.cross(a, b, dim=-1)
    return torch.atan2(torch.sqrt((c * c).sum(-1) + _SQRT_EPS), (a * b).sum(-1))
