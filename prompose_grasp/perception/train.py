"""Training the ProM-Pose network on the synthetic dataset (paper sections 3.7 and 4.1).

`train(data_dir, out_dir, ...)` reads the dataset's `train` and `val` splits (categories disjoint from `test`,
the zero-shot protocol), and optimises L = L_pose + 0.5 L_temp + 10 L_geo with Adam (beta 0.9 / 0.999,
weight decay 5e-4) and a cosine learning rate 1e-4 -> 1e-5, with colour jitter and up to 20 % point dropout.
Each step draws its windows and augmentation from `numpy.random.default_rng([seed, step])` and the model is
initialised after `torch.manual_seed(seed)`, so a run on the CPU is a function of the seed alone, and a
resumed run continues exactly as an uninterrupted one would.

Output folder: `last.pt` (checkpoint with optimiser and scheduler state; `load_estimator` reads it) and
`train_log.jsonl` (one JSON object per logged step: losses, learning rate, and validation errors when
evaluated). `main(argv)` is the `prompose-grasp train` command.

Across processes: `torchrun --nproc_per_node N -m prompose_grasp.perception.train --data DIR --out RUN ...`
(DistributedDataParallel, gloo on the CPU, nccl with `--device cuda`; `perception.distributed`). The global
batch (`--batch-size`, a multiple of N) is drawn as in one process and split by rank; rank 0 writes the
checkpoint and log; `--no-resume` aside, a restarted job resumes from `last.pt`. The loss curve equals one
process's with the same global batch up to the order of float additions (docs/scale.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console

from prompose_grasp.errors import InvalidInputError, PromposeError, UnknownNameError
from prompose_grasp.perception.network.checkpoint import load_checkpoint, load_state_strict, save_checkpoint
from prompose_grasp.perception.network.config import ABLATIONS, CONFIGS, NetworkConfig, network_config
from prompose_grasp.perception.network.data import (
    AugmentConfig,
    ObjectTrack,
    collate,
    load_tracks,
    make_windows,
)
from prompose_grasp.perception.network.losses import LossConfig, pose_loss, symmetric_rotation_error
from prompose_grasp.perception.network.model import ProMPoseNet

__all__ = ["TrainConfig", "TrainResult", "evaluate", "main", "train", "train_on_tracks"]

log = logging.getLogger(__name__)

CHECKPOINT_NAME = "last.pt"
LOG_NAME = "train_log.jsonl"


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (defaults: paper section 4.1).

    Attributes:
        steps: optimiser steps in total (a resumed run stops at the same total).
        batch_size: windows per step.
        lr, lr_min: cosine annealing from lr to lr_min over `steps`.
        weight_decay, betas: Adam's.
        loss: loss weights (lambda_geo = 10, lambda_temp = 0.5).
        augment: colour jitter and point dropout.
        val_every: evaluate on the validation tracks every this many steps (and before the first / after the
            last step); log_every: log training losses every this many steps; checkpoint_every: save.
        seed: the run's seed.
    """

    steps: int = 1000
    batch_size: int = 8
    lr: float = 1e-4
    lr_min: float = 1e-5
    weight_decay: float = 5e-4
    betas: tuple[float, float] = (0.9, 0.999)
    loss: LossConfig = field(default_factory=LossConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    val_every: int = 100
    log_every: int = 10
    checkpoint_every: int = 100
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "val_every", "log_every", "checkpoint_every"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidInputError(f"TrainConfig.{name} must be a positive int, got {v!r}")
        if not (0.0 < self.lr_min <= self.lr):
            raise InvalidInputError(f"need 0 < lr_min <= lr, got lr={self.lr}, lr_min={self.lr_min}")
        if self.weight_decay < 0.0:
            raise InvalidInputError(f"weight_decay must be >= 0, got {self.weight_decay}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class TrainResult:
    """What a training run did.

    Attributes:
        steps: total optimiser steps reached; resumed_from: the step the run started at (0 when fresh).
        val_first, val_last: validation errors at the run's first and last evaluation (`evaluate`'s dict).
        final_losses: training losses of the last step.
        checkpoint: path of `last.pt`; wall_s: wall time of this call [s].
    """

    steps: int
    resumed_from: int
    val_first: dict[str, float]
    val_last: dict[str, float]
    final_losses: dict[str, float]
    checkpoint: Path
    wall_s: float


@torch.no_grad()
def evaluate(
    model: ProMPoseNet,
    tracks: Sequence[ObjectTrack],
    batch_size: int = 8,
    device: str | torch.device = "cpu",
    loss: LossConfig | None = None,
) -> dict[str, float]:
    """Validation errors over every window of `tracks` (no augmentation), averaged over valid frames.

    Returns `rotation_deg` (symmetry-aware geodesic), `translation_cm` (Euclidean), `size_cm` (mean absolute
    per axis), `pose_loss` (L_pose) and `loss` (the weighted total), and `frames`.
    """
    if not tracks:
        raise InvalidInputError("no validation tracks")
    was_training = model.training
    model.eval()
    windows = make_windows(tracks, model.config.window)
    sums = {"rotation_deg": 0.0, "translation_cm": 0.0, "size_cm": 0.0, "pose_loss": 0.0, "loss": 0.0}
    frames = 0
    for i in range(0, len(windows), batch_size):
        batch = collate(tracks, windows[i : i + batch_size], model.config.window).to(device)
        out = model(**batch.inputs())
        valid = batch.frame_valid
        k = int(valid.sum())
        B, n = valid.shape
        rot = symmetric_rotation_error(out["R"], batch.R_cam_obj, batch.symmetry[:, None].expand(B, n))
        sums["rotation_deg"] += float(torch.rad2deg(rot)[valid].sum())
        sums["translation_cm"] += 100.0 * float((out["t"] - batch.t_cam_obj_m).norm(dim=-1)[valid].sum())
        sums["size_cm"] += 100.0 * float((out["size"] - batch.size_m).abs().mean(-1)[valid].sum())
        terms = pose_loss(
            out,
            batch.R_cam_obj,
            batch.t_cam_obj_m,
            batch.size_m,
            batch.symmetry,
            batch.points,
            out["prior_points"],
            valid,
            loss,
        )
        sums["pose_loss"] += float(terms["pose"]) * k
        sums["loss"] += float(terms["loss"]) * k
        frames += k
    model.train(was_training)
    return {**{key: v / max(frames, 1) for key, v in sums.items()}, "frames": float(frames)}


def _progress_bar(enabled: bool) -> Any:
    if not enabled:
        return None
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("train"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[info]}"),
        TimeRemainingColumn(),
    )


def train_on_tracks(
    train_tracks: Sequence[ObjectTrack],
    val_tracks: Sequence[ObjectTrack],
    config: NetworkConfig,
    train_config: TrainConfig,
    out_dir: str | Path,
    *,
    device: str | torch.device = "cpu",
    resume: bool = True,
    progress: bool = False,
    stop_at: int | None = None,
) -> TrainResult:
    """Train a `ProMPoseNet` on preprocessed tracks; checkpoints and logs go to `out_dir`.

    With `resume` and an existing `out_dir/last.pt`, the run continues from it (same network config
    required) up to `train_config.steps`. `stop_at` ends this call after that many total steps (with a
    checkpoint), as an interruption would; the schedule still spans `train_config.steps`.

    In a process group of several processes (`torchrun`, `perception.distributed`), each rank trains on its
    shard of every global batch of `train_config.batch_size` windows under DistributedDataParallel; the
    logged losses are the global batch's; rank 0 writes the checkpoint and the log.
    """
    from prompose_grasp.perception.distributed import current_context

    ctx = current_context(device)
    if ctx is not None:
        device = ctx.device
        ctx.shard(train_config.batch_size)  # fails early on a batch that does not split evenly
    main_rank = ctx is None or ctx.is_main
    t0 = time.perf_counter()
    if not train_tracks:
        raise InvalidInputError("no training tracks: does the dataset's train split hold any objects?")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / CHECKPOINT_NAME
    tc = train_config
    torch.manual_seed(tc.seed)  # every rank initialises the same network (DDP also broadcasts rank 0's)
    model = ProMPoseNet(config).to(device)
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(params, lr=tc.lr, betas=tc.betas, weight_decay=tc.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=tc.steps, eta_min=tc.lr_min)
    start = 0
    if resume and ckpt_path.is_file():
        ckpt = load_checkpoint(ckpt_path, map_location=device)
        stored = NetworkConfig.from_dict(ckpt["config"])
        if stored != config:
            raise InvalidInputError(
                f"{ckpt_path} was trained with a different network config; use another --out or drop --resume"
            )
        load_state_strict(model, ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        scheduler.load_state_dict(ckpt["scheduler"])
        start = int(ckpt["step"])
        log.info("resuming from %s at step %d", ckpt_path, start)
    elif main_rank and (out / LOG_NAME).exists():
        (out / LOG_NAME).unlink()  # a fresh run does not append to an old run's log
    net: torch.nn.Module = model
    if ctx is not None:
        from torch.nn.parallel import DistributedDataParallel

        ids = [ctx.device.index] if ctx.device.type == "cuda" else None
        # no_temporal leaves the temporal position embedding out of the forward pass (checked for every
        # ablation): DDP must not wait for its gradient
        net = DistributedDataParallel(model, device_ids=ids, find_unused_parameters=config.temporal is False)

    end = tc.steps if stop_at is None else max(min(int(stop_at), tc.steps), start)
    windows = make_windows(train_tracks, config.window, stride=1)
    log_file = (out / LOG_NAME).open("a") if main_rank else None

    def write(record: dict[str, Any]) -> None:
        if log_file is not None:
            log_file.write(json.dumps(record) + "\n")
            log_file.flush()

    def save(step: int) -> None:
        if not main_rank:
            return
        save_checkpoint(
            ckpt_path,
            model,
            step,
            optimizer=optimizer.state_dict(),
            scheduler=scheduler.state_dict(),
            train_config=json.dumps(tc.to_dict()),
        )

    # validation on rank 0 only (the others would compute the same numbers)
    validate = bool(val_tracks) and main_rank
    val_first = evaluate(model, val_tracks, tc.batch_size, device, tc.loss) if validate else {}
    if val_tracks:
        write({"step": start, "val": val_first})
    val_last = val_first
    losses: dict[str, float] = {}
    bar = _progress_bar(progress and main_rank)
    task = bar.add_task("train", total=end, completed=start, info="") if bar is not None else None
    model.train()
    try:
        if bar is not None:
            bar.start()
        for step in range(start, end):
            rng = np.random.default_rng([tc.seed, step])
            pick = rng.choice(len(windows), size=tc.batch_size, replace=len(windows) < tc.batch_size)
            batch = collate(train_tracks, [windows[i] for i in pick], config.window, rng, tc.augment)
            denominators = None
            if ctx is not None:
                # the global batch was drawn and augmented as one process does; this rank keeps its shard,
                # and its loss is its part of the global batch's (global valid-frame and window counts)
                denominators = (float(batch.frame_valid.sum()), float(tc.batch_size))
                batch = batch.rows(*ctx.shard(tc.batch_size))
            batch = batch.to(device)
            outputs = net(**batch.inputs())
            terms = pose_loss(
                outputs,
                batch.R_cam_obj,
                batch.t_cam_obj_m,
                batch.size_m,
                batch.symmetry,
                batch.points,
                outputs["prior_points"],
                batch.frame_valid,
                tc.loss,
                denominators=denominators,
            )
            if ctx is not None:
                losses = ctx.all_sum(terms)  # the global batch's terms (identical on every rank)
            else:
                losses = {k: float(v.detach()) for k, v in terms.items()}
            if not math.isfinite(losses["loss"]):
                raise PromposeError(f"training diverged at step {step}: loss {losses['loss']}")
            optimizer.zero_grad(set_to_none=True)
            # DDP averages the ranks' gradients (sum / world size); the shards' losses sum to the global loss
            loss = terms["loss"] if ctx is None else terms["loss"] * ctx.world_size
            loss.backward()
            optimizer.step()
            scheduler.step()
            done = step + 1
            record: dict[str, Any] = {}
            if done % tc.log_every == 0 or done == end:
                record.update(step=done, lr=optimizer.param_groups[0]["lr"], **losses)
            if validate and (done % tc.val_every == 0 or done == end):
                val_last = evaluate(model, val_tracks, tc.batch_size, device, tc.loss)
                record.update(step=done, val=val_last)
            if record:
                write(record)
            if done % tc.checkpoint_every == 0 or done == end:
                save(done)
            if bar is not None and task is not None:
                bar.update(task, completed=done, info=f"loss {losses['loss']:.3f}")
    finally:
        if bar is not None:
            bar.stop()
        if log_file is not None:
            log_file.close()
    if start >= end and not ckpt_path.is_file():
        save(start)
    if ctx is not None:
        ctx.barrier()  # the checkpoint is written before any rank returns (and reads or resumes it)
    return TrainResult(
        steps=max(start, end),
        resumed_from=start,
        val_first=val_first,
        val_last=val_last,
        final_losses=losses,
        checkpoint=ckpt_path,
        wall_s=time.perf_counter() - t0,
    )


def train(
    data_dir: str | Path,
    out_dir: str | Path,
    network: str = "tiny",
    train_config: TrainConfig | None = None,
    *,
    epochs: int | None = None,
    device: str | torch.device = "cpu",
    resume: bool = True,
    progress: bool = True,
    text_encoder: Any = None,
    max_scenes: int | None = None,
    ablation: str = "full",
) -> TrainResult:
    """Train the named network config on a synthetic dataset folder (see the module docstring).

    Args:
        data_dir: folder written by `python -m sim.dataset`.
        out_dir: checkpoint and log folder.
        network: `tiny` or `paper` (`network.CONFIGS`); its text_dim is set from the text encoder.
        train_config: optimisation settings (default `TrainConfig()`).
        epochs: if given, overrides `train_config.steps` with epochs x ceil(windows / batch size).
        device: torch device.
        resume: continue from `out_dir/last.pt` when it exists.
        progress: show a progress bar.
        text_encoder: the frozen phi_T (default: the embedded MiniLM, `default_text_encoder(device)`).
        max_scenes: read only the first scenes of each split (quick runs).
        ablation: one of `network.config.ABLATIONS` (paper Table 2); "without L_geo" is
            `train_config.loss.lambda_geo = 0`.
    """
    from prompose_grasp.perception.text import default_text_encoder

    tc = train_config or TrainConfig()
    encoder = text_encoder or default_text_encoder("cpu")
    config = network_config(network, ablation, text_dim=int(encoder.dim))
    train_tracks = load_tracks(data_dir, "train", config, encoder, max_scenes=max_scenes)
    val_tracks = load_tracks(data_dir, "val", config, encoder, max_scenes=max_scenes)
    if epochs is not None:
        if epochs < 1:
            raise InvalidInputError(f"epochs must be >= 1, got {epochs}")
        n_windows = len(make_windows(train_tracks, config.window, stride=1))
        tc = TrainConfig(**{**tc.__dict__, "steps": epochs * math.ceil(n_windows / tc.batch_size)})
    log.info(
        "training %s on %d train / %d val tracks for %d steps",
        network,
        len(train_tracks),
        len(val_tracks),
        tc.steps,
    )
    return train_on_tracks(
        train_tracks, val_tracks, config, tc, out_dir, device=device, resume=resume, progress=progress
    )


#: The training-side ablation of paper Table 2 (the others are `network.config.ABLATIONS`).
NO_GEO_LOSS = "no_geo_loss"
#: Every ablation of the study, in table order.
ABLATION_STUDY = (*ABLATIONS, NO_GEO_LOSS)


def train_ablation_study(
    data_dir: str | Path,
    out_dir: str | Path,
    network: str = "tiny",
    train_config: TrainConfig | None = None,
    *,
    ablations: Sequence[str] = ABLATION_STUDY,
    device: str | torch.device = "cpu",
    resume: bool = True,
    progress: bool = True,
    text_encoder: Any = None,
    max_scenes: int | None = None,
) -> dict[str, TrainResult]:
    """Train each ablation of paper Table 2 with the same data, seed and schedule into `out_dir/NAME`.

    The tracks are loaded once (every ablation keeps the input sizes); `no_geo_loss` is the full network
    trained with lambda_geo = 0. Returns {name: TrainResult}.
    """
    from prompose_grasp.perception.text import default_text_encoder

    unknown = [a for a in ablations if a not in ABLATION_STUDY]
    if unknown:
        raise UnknownNameError("ablation", unknown[0], ABLATION_STUDY)
    tc = train_config or TrainConfig()
    encoder = text_encoder or default_text_encoder("cpu")
    base = network_config(network, text_dim=int(encoder.dim))
    train_tracks = load_tracks(data_dir, "train", base, encoder, max_scenes=max_scenes)
    val_tracks = load_tracks(data_dir, "val", base, encoder, max_scenes=max_scenes)
    results = {}
    for name in ablations:
        config = network_config(network, "full" if name == NO_GEO_LOSS else name, text_dim=int(encoder.dim))
        run_tc = replace(tc, loss=replace(tc.loss, lambda_geo=0.0)) if name == NO_GEO_LOSS else tc
        log.info("ablation %s: %d steps into %s", name, run_tc.steps, Path(out_dir) / name)
        results[name] = train_on_tracks(
            train_tracks,
            val_tracks,
            config,
            run_tc,
            Path(out_dir) / name,
            device=device,
            resume=resume,
            progress=progress,
        )
    return results


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """Arguments of `prompose-grasp train` (added to `parser` when given, e.g. a CLI sub-command)."""
    p = parser or argparse.ArgumentParser(prog="prompose-grasp train", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="dataset folder written by `python -m sim.dataset`")
    p.add_argument("--out", required=True, help="checkpoint / log folder (last.pt, train_log.jsonl)")
    p.add_argument("--config", default="tiny", choices=sorted(CONFIGS), help="network size (default tiny)")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--steps", type=int, default=None, help="optimiser steps (default 1000)")
    length.add_argument("--epochs", type=int, default=None, help="passes over the training windows")
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--lr", type=float, default=1e-4, help="initial learning rate (cosine to --lr-min)")
    p.add_argument("--lr-min", type=float, default=1e-5)
    p.add_argument(
        "--ablation",
        default="full",
        choices=sorted(ABLATIONS),
        help="train a paper Table 2 ablation instead of the full network (default full)",
    )
    p.add_argument(
        "--ablation-study",
        action="store_true",
        help=f"train every ablation ({', '.join(ABLATION_STUDY)}) in turn into OUT/NAME, tracks loaded once",
    )
    p.add_argument(
        "--lambda-geo",
        type=float,
        default=LossConfig().lambda_geo,
        help="weight of L_geo (paper: 10; 0 = the 'without L_geo' ablation)",
    )
    p.add_argument("--device", default="cpu", help="torch device: cpu, cuda, cuda:1 (default cpu)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="CPU threads for torch (default 1)")
    p.add_argument("--val-every", type=int, default=100)
    p.add_argument("--max-scenes", type=int, default=None, help="read only this many scenes per split")
    p.add_argument("--no-resume", action="store_true", help="start afresh even if OUT/last.pt exists")
    p.add_argument("--no-progress", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """`prompose-grasp train ...`: returns the exit status (2 with a one-line message on bad input)."""
    args = build_parser().parse_args(argv)
    return run(args)


def run(args: argparse.Namespace) -> int:
    """Run a parsed `prompose-grasp train` command (one of the processes when `torchrun` started it)."""
    from prompose_grasp.perception.distributed import init_from_env

    try:
        ctx = init_from_env(args.device)
    except (RuntimeError, ValueError) as err:
        Console(stderr=True).print(f"error: could not join the process group: {err}", markup=False)
        return 2
    try:
        return _run(args, quiet=ctx is not None and not ctx.is_main)
    finally:
        if ctx is not None:
            torch.distributed.destroy_process_group()


def _run(args: argparse.Namespace, quiet: bool) -> int:
    try:
        torch.set_num_threads(max(int(args.threads), 1))
        tc = TrainConfig(
            steps=args.steps or 1000,
            batch_size=args.batch_size,
            lr=args.lr,
            lr_min=args.lr_min,
            val_every=args.val_every,
            seed=args.seed,
            loss=LossConfig(lambda_geo=args.lambda_geo),
        )
        if args.ablation_study:
            results = train_ablation_study(
                args.data,
                args.out,
                args.config,
                tc,
                device=args.device,
                resume=not args.no_resume,
                progress=not args.no_progress,
                max_scenes=args.max_scenes,
            )
            summary = {k: {"val_last": r.val_last, "wall_s": round(r.wall_s, 1)} for k, r in results.items()}
            Console().print(json.dumps(summary), markup=False, highlight=False, soft_wrap=True)
            return 0
        result = train(
            args.data,
            args.out,
            args.config,
            tc,
            epochs=args.epochs,
            device=args.device,
            resume=not args.no_resume,
            progress=not args.no_progress,
            max_scenes=args.max_scenes,
            ablation=args.ablation,
        )
    except PromposeError as err:
        Console(stderr=True).print(f"error: {err}", markup=False, highlight=False)
        return 2
    if quiet:  # rank 0 reports for the job
        return 0
    Console().print(
        json.dumps(
            {
                "steps": result.steps,
                "resumed_from": result.resumed_from,
                "val_first": result.val_first,
                "val_last": result.val_last,
                "checkpoint": str(result.checkpoint),
                "wall_s": round(result.wall_s, 1),
            }
        ),
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
