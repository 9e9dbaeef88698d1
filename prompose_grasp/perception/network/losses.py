"""Training objectives of paper section 3.7: L = L_pose + lambda_temp L_temp + lambda_geo L_geo.

- L_pose = mean over valid frames of L_R + L_T + L_S, with L_R = |log(R^_t^T R_t)| (the geodesic angle, rad),
  L_T = |T^_t - T_t|_1 and L_S = |S^_t - S_t|_1 [m].
- Symmetric objects (the prior/asset symmetry tags, `priors.SYMMETRIES`): L_R is the smallest angle to any
  ground-truth rotation that looks the same. `y_continuous`: only the y axes are compared (the angle between
  R^ e_y and R e_y); `x_continuous`: the x axes up to sign (rotation about x and the end-over-end flip);
  `box`: the minimum over the four 180-degree turns {I, Rx(pi), Ry(pi), Rz(pi)}; `y_2fold`: over {I, Ry(pi)};
  `spherical`: 0; `none`: the full geodesic.
- L_temp = sum over adjacent valid frame pairs of |T^_t - T^_{t-1}|^2 + |log(R^_{t-1}^T R^_t)|^2
  + |S^_t - S^_{t-1}|^2 (per window; averaged over the batch).
- L_geo = mean over valid frames of the bidirectional squared Chamfer distance [m^2] between the posed prior
  R^ diag(S^) x + T^ and the observed (mask-filtered) points.
Paper weights: lambda_geo = 10, lambda_temp = 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.perception.network.rotations import axis_angle_between, geodesic_angle
from prompose_grasp.perception.priors.prior import SYMMETRIES

__all__ = [
    "LossConfig",
    "chamfer_squared",
    "pose_loss",
    "symmetric_rotation_error",
    "symmetry_codes",
]


@dataclass(frozen=True)
class LossConfig:
    """Loss weights (paper section 4.1 values)."""

    lambda_geo: float = 10.0
    lambda_temp: float = 0.5

    def __post_init__(self) -> None:
        for name in ("lambda_geo", "lambda_temp"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not v >= 0.0:
                raise InvalidInputError(f"LossConfig.{name} must be a number >= 0, got {v!r}")


def symmetry_codes(tags: list[str] | tuple[str, ...]) -> Tensor:
    """Symmetry tags -> (len,) long codes (their index in `SYMMETRIES`)."""
    out = []
    for tag in tags:
        if tag not in SYMMETRIES:
            raise UnknownNameError("symmetry", tag, SYMMETRIES)
        out.append(SYMMETRIES.index(tag))
    return torch.tensor(out, dtype=torch.long)


def _flip(diag: tuple[float, float, float], like: Tensor) -> Tensor:
    return torch.diag(torch.tensor(diag, dtype=like.dtype, device=like.device))


def symmetric_rotation_error(R_pred: Tensor, R_true: Tensor, codes: Tensor) -> Tensor:
    """Symmetry-aware rotation error [rad].

    R_pred, R_true: (..., 3, 3); codes: (...) long (`symmetry_codes`). Returns (...) angles in [0, pi].
    """
    full = geodesic_angle(R_pred, R_true)
    turns = [_flip(d, R_true) for d in ((1, -1, -1), (-1, 1, -1), (-1, -1, 1))]  # Rx(pi), Ry(pi), Rz(pi)
    box = torch.stack([full] + [geodesic_angle(R_pred, R_true @ G) for G in turns], dim=-1).amin(-1)
    y2 = torch.minimum(full, geodesic_angle(R_pred, R_true @ turns[1]))
    y_axis = axis_angle_between(R_pred[..., :, 1], R_true[..., :, 1])
    x_pred, x_true = R_pred[..., :, 0], R_true[..., :, 0]
    x_axis = torch.minimum(axis_angle_between(x_pred, x_true), axis_angle_between(x_pred, -x_true))
    by_code = {
        "none": full,
        "y_continuous": y_axis,
        "x_continuous": x_axis,
        "box": box,
        "spherical": torch.zeros_like(full),
        "y_2fold": y2,
    }
    out = full
    for name, value in by_code.items():
        out = torch.where(codes == SYMMETRIES.index(name), value, out)
    return out


def chamfer_squared(a: Tensor, b: Tensor) -> Tensor:
    """Bidirectional squared Chamfer distance of (B, N, 3) and (B, M, 3) clouds -> (B,) [m^2]."""
    d = torch.cdist(a, b) ** 2
    return d.amin(dim=2).mean(dim=1) + d.amin(dim=1).mean(dim=1)


def _masked_mean(x: Tensor, valid: Tensor, count: float | None = None) -> Tensor:
    """Mean of x over the valid entries; with `count`, the sum divided by that many (a shard's part of a
    larger batch's mean)."""
    w = valid.to(x.dtype)
    if count is not None:
        return (x * w).sum() / max(float(count), 1.0)
    return (x * w).sum() / w.sum().clamp_min(1.0)


def pose_loss(
    outputs: dict[str, Tensor],
    R_true: Tensor,
    t_true: Tensor,
    size_true: Tensor,
    symmetry: Tensor,
    points: Tensor,
    prior_points: Tensor,
    frame_valid: Tensor,
    config: LossConfig | None = None,
    denominators: tuple[float, float] | None = None,
) -> dict[str, Tensor]:
    """All loss terms of a batch of windows.

    Args:
        outputs: the network's dict (`R` (B, n, 3, 3), `t` (B, n, 3), `size` (B, n, 3)).
        R_true, t_true, size_true: ground truth, same shapes [m].
        symmetry: (B,) long symmetry codes.
        points: (B, n, N, 3) observed points [m]; prior_points: (B, Np, 3) unit box.
        frame_valid: (B, n) bool.
        denominators: (valid frames, windows) of the global batch this one is a shard of (data-parallel
            training): each term is then this shard's part of the global batch's term, so that the terms of
            all shards sum to the global batch's. None: this batch alone.
    Returns:
        `loss` (the weighted total), `pose`, `rotation`, `translation`, `scale`, `temporal`, `geo`; scalars.
    """
    cfg = config or LossConfig()
    R, t, size = outputs["R"], outputs["t"], outputs["size"]
    B, n = R.shape[:2]
    valid = frame_valid
    n_valid, n_windows = denominators if denominators is not None else (None, B)
    rot = symmetric_rotation_error(R, R_true, symmetry[:, None].expand(B, n))
    trans = (t - t_true).abs().sum(-1)
    scale = (size - size_true).abs().sum(-1)
    l_rot, l_trans, l_scale = (
        _masked_mean(rot, valid, n_valid),
        _masked_mean(trans, valid, n_valid),
        _masked_mean(scale, valid, n_valid),
    )
    l_pose = l_rot + l_trans + l_scale

    if n > 1:
        pair = valid[:, 1:] & valid[:, :-1]
        step = (
            ((t[:, 1:] - t[:, :-1]) ** 2).sum(-1)
            + geodesic_angle(R[:, :-1], R[:, 1:]) ** 2
            + ((size[:, 1:] - size[:, :-1]) ** 2).sum(-1)
        )
        l_temp = (step * pair.to(step.dtype)).sum() / n_windows
    else:
        l_temp = R.new_zeros(())

    posed = (prior_points[:, None] * size[:, :, None, :]) @ R.transpose(-1, -2) + t[:, :, None, :]
    cd = chamfer_squared(posed.reshape(B * n, *posed.shape[2:]), points.reshape(B * n, *points.shape[2:]))
    l_geo = _masked_mean(cd.reshape(B, n), valid, n_valid)

    total = l_pose + cfg.lambda_temp * l_temp + cfg.lambda_geo * l_geo
    return {
        "loss": total,
        "pose": l_pose,
        "rotation": l_rot,
        "translation": l_trans,
        "scale": l_scale,
        "temporal": l_temp,
        "geo": l_geo,
    }
