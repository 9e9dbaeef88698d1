"""Checkpoints: the network's config travels with its weights; `load_estimator` rebuilds and loads strictly.

A checkpoint is one `torch.save` dict (readable with `weights_only=True`):
`{"format": "prompose-grasp/network", "version": 1, "config": NetworkConfig.to_dict(), "model": state_dict,
"step": int, ...}` plus, for training checkpoints, optimiser / scheduler state and the training config.

Frozen backbones are not stored: with `visual_backbone="dinov2"` the DINOv2 weights (`visual.backbone.*`) come
from the local DINOv2 folder, and loading requires every other key to match exactly (no missing, no
unexpected keys), which is `strict=True` on the trained part.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch
from torch import nn

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.model import ProMPoseNet

__all__ = [
    "CHECKPOINT_FORMAT",
    "SHIPPED_WEIGHTS",
    "export_weights",
    "load_checkpoint",
    "load_estimator",
    "save_checkpoint",
    "trained_state_dict",
]

log = logging.getLogger(__name__)

#: The checkpoint shipped with the package: the `tiny` config trained on CPU on a generated synthetic set
#: (how and on what: its `trained_on` and `command` entries; numbers: docs/benchmarks.md, "network").
SHIPPED_WEIGHTS = Path(__file__).parent / "weights" / "prompose_tiny.pt"

CHECKPOINT_FORMAT = "prompose-grasp/network"
CHECKPOINT_VERSION = 1
#: State-dict keys of frozen backbones loaded from their own local weights, never from a checkpoint.
_FROZEN_PREFIXES = ("visual.backbone.",)


def trained_state_dict(model: nn.Module) -> dict[str, torch.Tensor]:
    """The model's state dict without frozen backbones (what a checkpoint stores)."""
    return {k: v for k, v in model.state_dict().items() if not k.startswith(_FROZEN_PREFIXES)}


def save_checkpoint(path: str | Path, model: ProMPoseNet, step: int = 0, **extra: Any) -> Path:
    """Write `model` (config + trained weights) and `extra` entries to `path` atomically; returns the path."""
    if not isinstance(model, ProMPoseNet):
        raise InvalidInputError(f"model must be a ProMPoseNet, got {type(model).__name__}")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "config": model.config.to_dict(),
        "model": trained_state_dict(model),
        "step": int(step),
        **extra,
    }
    tmp = out.with_name(out.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(out)  # a crash mid-write never leaves a truncated checkpoint behind
    return out


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The raw checkpoint dict (validated format); tensors on `map_location`."""
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"checkpoint {str(p)!r} not found")
    ckpt = torch.load(p, map_location=map_location, weights_only=True)
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InvalidInputError(
            f"{p} is not a prompose-grasp network checkpoint (format {CHECKPOINT_FORMAT!r})"
        )
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise InvalidInputError(
            f"{p} has checkpoint version {ckpt.get('version')}; this library reads {CHECKPOINT_VERSION}"
        )
    return ckpt


def export_weights(src: str | Path, dst: str | Path, **provenance: Any) -> Path:
    """Copy a training checkpoint to `dst` without its optimiser and scheduler state (what one ships), with
    `provenance` entries (how and on what it was trained) added; the weights are unchanged."""
    ckpt = load_checkpoint(src)
    model = ProMPoseNet(NetworkConfig.from_dict(ckpt["config"]))
    load_state_strict(model, ckpt["model"])
    keep = {"train_config": ckpt["train_config"]} if "train_config" in ckpt else {}
    return save_checkpoint(dst, model, int(ckpt["step"]), **keep, **provenance)


def load_state_strict(model: nn.Module, state: dict[str, torch.Tensor]) -> None:
    """Load `state` into `model`; every key must match except frozen-backbone keys absent from `state`."""
    missing, unexpected = model.load_state_dict(state, strict=False)
    missing = [k for k in missing if not k.startswith(_FROZEN_PREFIXES)]
    if missing or unexpected:
        raise InvalidInputError(
            f"checkpoint does not match the network: missing keys {missing[:8]}, "
            f"unexpected keys {unexpected[:8]}"
        )


def load_estimator(
    weights: str | Path, device: str | torch.device = "cpu", dinov2_dir: str | Path | None = None
) -> ProMPoseNet:
    """The network of a checkpoint, built from its stored config, weights loaded strictly, in eval mode.

    Args:
        weights: checkpoint file written by `save_checkpoint` (or `prompose-grasp train`).
        device: torch device to load onto ("cpu", "cuda", "cuda:1").
        dinov2_dir: local DINOv2 folder for `visual_backbone="dinov2"` checkpoints (default: the stored one).
    """
    ckpt = load_checkpoint(weights, map_location="cpu")
    config = NetworkConfig.from_dict(ckpt["config"])
    model = ProMPoseNet(config, dinov2_dir=dinov2_dir)
    load_state_strict(model, ckpt["model"])
    model.to(device)
    model.eval()
    log.info("loaded %s network (step %d) from %s on %s", "ProM-Pose", ckpt["step"], weights, device)
    return model
