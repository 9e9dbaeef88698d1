"""Data-parallel training (`perception.distributed`, as `torchrun --nproc_per_node 2` runs it): two real
processes joined over gloo with torchrun's env:// initialisation give the loss curve of one process with the
same global batch; rank 0 alone writes the checkpoint; an interrupted two-process run resumes from it."""

from __future__ import annotations

import json
import os
import socket

import pytest
import torch
import torch.multiprocessing as mp
from network_fixtures import synthetic_tracks

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.distributed import DistributedContext, init_from_env
from prompose_grasp.perception.network import network_config
from prompose_grasp.perception.network.checkpoint import load_checkpoint
from prompose_grasp.perception.train import TrainConfig, train_on_tracks

TINY = network_config("tiny")
# 4 global windows per step: 2 per rank; log every step so the whole curve is compared
TC = TrainConfig(steps=4, batch_size=4, lr=1e-3, lr_min=1e-4, val_every=100, log_every=1, seed=3)


def _tracks():
    return synthetic_tracks(TINY, 8, 4, seed=0), synthetic_tracks(TINY, 2, 4, seed=1)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rank_main(rank: int, world: int, port: int, out: str) -> None:
    # what torchrun sets for each process it starts
    os.environ.update(
        RANK=str(rank),
        LOCAL_RANK=str(rank),
        WORLD_SIZE=str(world),
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
    )
    torch.set_num_threads(1)
    ctx = init_from_env("cpu")
    assert ctx is not None and (ctx.rank, ctx.world_size) == (rank, world)
    train, val = _tracks()
    try:
        first = train_on_tracks(train, val, TINY, TC, out, resume=False, stop_at=2)  # interrupted at step 2
        assert first.steps == 2
        again = train_on_tracks(train, val, TINY, TC, out, resume=True)
        assert (again.resumed_from, again.steps) == (2, 4)
    finally:
        torch.distributed.destroy_process_group()


def _curve(folder) -> list[dict]:
    lines = [json.loads(x) for x in (folder / "train_log.jsonl").read_text().splitlines()]
    return [r for r in lines if "loss" in r]


def test_two_processes_match_one_with_the_same_global_batch(tmp_path):
    torch.set_num_threads(1)
    train, val = _tracks()
    single = train_on_tracks(train, val, TINY, TC, tmp_path / "one", resume=False)
    assert single.steps == 4
    mp.start_processes(
        _rank_main, args=(2, _free_port(), str(tmp_path / "two")), nprocs=2, start_method="spawn"
    )

    one, two = _curve(tmp_path / "one"), _curve(tmp_path / "two")
    assert [r["step"] for r in two] == [1, 2, 3, 4]  # one log, by rank 0, across the resume
    for a, b in zip(one, two):
        for key in ("loss", "pose", "rotation", "translation", "scale", "temporal", "geo"):
            # float32 sums in another order (two shards, then an all-reduce) differ by ~1e-7 relative at step
            # 1; Adam's normalised steps amplify rounding noise in weights with near-zero gradients, so the
            # gap grows (measured: <= 4e-6 relative by step 4). 1e-4 leaves a margin of 25 and is still 1e3
            # times below the loss's change between steps, so a wrong shard or normalisation fails.
            assert b[key] == pytest.approx(a[key], rel=1e-4, abs=1e-7), (b["step"], key)
        assert b["lr"] == a["lr"]
    w1 = load_checkpoint(tmp_path / "one" / "last.pt")["model"]
    w2 = load_checkpoint(tmp_path / "two" / "last.pt")["model"]
    assert w1.keys() == w2.keys()  # rank 0 saved the bare network, not the DDP wrapper
    # Adam moves every weight by at most ~lr per step in either run, so no difference exceeds 2 lr steps.
    # The attention key biases (in_proj_bias[d:2d]) get no true gradient (softmax(q.(k + b)) does not depend
    # on b), only rounding noise, which Adam's normalisation turns into lr-sized steps whose sign depends on
    # the summation order: they may differ up to that bound. Every other weight agrees to 1e-6 but for a
    # handful of entries with near-zero gradients (measured: 3 of 357k).
    bound = 2 * TC.lr * TC.steps
    off = total = 0
    for k in w1:
        if not w1[k].is_floating_point():
            continue
        diff = (w1[k] - w2[k]).abs().flatten()
        assert float(diff.max()) <= bound, k
        if k.endswith("in_proj_bias"):
            d = diff.numel() // 3
            diff = torch.cat([diff[:d], diff[2 * d :]])
        off += int((diff > 1e-6).sum())
        total += diff.numel()
    assert off <= 1e-4 * total


def test_global_batch_must_split_evenly():
    ctx = DistributedContext(1, 2, torch.device("cpu"))
    assert ctx.shard(4) == (2, 4)
    with pytest.raises(InvalidInputError, match="multiple of the process count"):
        ctx.shard(5)


def test_a_lone_process_needs_no_group(monkeypatch):
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    assert init_from_env("cpu") is None
