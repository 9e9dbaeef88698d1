"""Training: a short run lowers the validation pose error; a resumed run equals an uninterrupted one; the
dataset reader on a generated sim dataset (zero-shot split, points inside the ground-truth boxes); the
`train` command end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from network_fixtures import synthetic_tracks

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.perception.network import load_estimator, network_config
from prompose_grasp.perception.network.checkpoint import load_checkpoint
from prompose_grasp.perception.train import (
    ABLATION_STUDY,
    NO_GEO_LOSS,
    TrainConfig,
    evaluate,
    main,
    train_on_tracks,
)

torch.set_num_threads(1)
TINY = network_config("tiny")


@pytest.fixture(scope="module")
def tracks():
    return synthetic_tracks(TINY, 12, 4, seed=0), synthetic_tracks(TINY, 4, 4, seed=1)


def test_short_training_lowers_validation_pose_error(tracks, tmp_path):
    train, val = tracks
    tc = TrainConfig(steps=12, batch_size=4, lr=1e-3, lr_min=1e-4, val_every=100, seed=0)
    result = train_on_tracks(train, val, TINY, tc, tmp_path, resume=False)
    assert result.steps == 12 and result.resumed_from == 0
    before, after = result.val_first, result.val_last
    assert after["pose_loss"] < 0.9 * before["pose_loss"], (before, after)
    # the stored checkpoint is the trained model: evaluating it again gives the logged numbers
    model = load_estimator(result.checkpoint)
    again = evaluate(model, val, batch_size=4)
    assert again["pose_loss"] == pytest.approx(after["pose_loss"], rel=1e-6)  # same float32 computation
    lines = [json.loads(x) for x in (tmp_path / "train_log.jsonl").read_text().splitlines()]
    assert lines[0]["step"] == 0 and "val" in lines[0] and lines[-1]["step"] == 12
    assert all(np.isfinite(r["loss"]) for r in lines if "loss" in r)


def test_resumed_training_equals_uninterrupted(tracks, tmp_path):
    train, val = tracks[0][:4], tracks[1][:1]
    tc = TrainConfig(steps=3, batch_size=2, lr=1e-3, lr_min=1e-4, val_every=100, seed=5)
    straight = train_on_tracks(train, val, TINY, tc, tmp_path / "a", resume=False)
    interrupted = train_on_tracks(train, val, TINY, tc, tmp_path / "b", resume=False, stop_at=2)
    assert (straight.steps, interrupted.steps) == (3, 2)
    resumed = train_on_tracks(train, val, TINY, tc, tmp_path / "b", resume=True)
    assert (resumed.resumed_from, resumed.steps) == (2, 3)
    a = load_checkpoint(tmp_path / "a" / "last.pt")
    b = load_checkpoint(tmp_path / "b" / "last.pt")
    # seeded CPU training is a function of (seed, step): bit-identical weights and optimiser state
    assert a["model"].keys() == b["model"].keys()
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    assert resumed.final_losses == straight.final_losses
    with pytest.raises(InvalidInputError, match="different network config"):
        train_on_tracks(train, val, TINY.with_(latent_dim=32), tc, tmp_path / "b", resume=True)


@pytest.fixture(scope="module")
def sim_dataset(tmp_path_factory):
    from sim.dataset import DatasetConfig, generate

    out = tmp_path_factory.mktemp("sim_data")
    # 10 scenes: 7 train, 1 val, 2 test (the generator's 70/10/20 split)
    generate(
        DatasetConfig(out=str(out), scenes=10, frames=2, seed=3, width=160, height=120, workers=1), False
    )
    return out


@pytest.mark.sim
@pytest.mark.slow
def test_load_tracks_from_a_generated_dataset(sim_dataset):
    from prompose_grasp.perception.dataset import read_split
    from prompose_grasp.perception.network import load_tracks
    from prompose_grasp.perception.text import default_text_encoder

    split = read_split(sim_dataset)
    encoder = default_text_encoder()
    by_split = {
        s: load_tracks(sim_dataset, s, TINY, encoder, min_points=16) for s in ("train", "val", "test")
    }
    test_cats = set(split["test"]["categories"])
    assert by_split["train"] and by_split["test"]
    assert all(t.category not in test_cats for s in ("train", "val") for t in by_split[s])  # zero-shot
    assert all(t.category in test_cats for t in by_split["test"])
    for tr in by_split["train"]:
        assert tr.crops.shape == (2, TINY.crop_px, TINY.crop_px, 3) and tr.crops.max() > 0
        assert tr.points.shape == (2, TINY.observed_points, 3) and tr.prior_points.shape == (
            TINY.prior_points,
            3,
        )
        assert tr.text_tokens.shape[1] == encoder.dim
        for f in np.flatnonzero(tr.frame_valid):
            box = Pose9D(tr.R_cam_obj[f], tr.t_cam_obj_m[f], tr.size_m[f])
            # depth noise (~2 mm at 0.5 m), edge pixels mixing object and background: 90 % within 1 cm
            assert box.contains(tr.points[f], margin_m=0.01).mean() > 0.9


@pytest.mark.sim
@pytest.mark.slow
def test_train_command_end_to_end(sim_dataset, tmp_path):
    out = tmp_path / "run"
    common = ["--data", str(sim_dataset), "--out", str(out), "--config", "tiny", "--batch-size", "4"]
    fast = ["--lr", "1e-3", "--lr-min", "1e-4", "--no-progress"]
    assert main([*common, *fast, "--steps", "12", "--val-every", "12"]) == 0
    model = load_estimator(weights=out / "last.pt", device="cpu")
    assert model.config.window == TINY.window and load_checkpoint(out / "last.pt")["step"] == 12
    log = [json.loads(x) for x in (out / "train_log.jsonl").read_text().splitlines()]
    vals = [r["val"] for r in log if "val" in r]
    assert [r["step"] for r in log if "val" in r] == [0, 12]
    # a handful of steps on unseen val instances already lowers the pose error
    assert vals[-1]["pose_loss"] < vals[0]["pose_loss"], vals
    # a longer run resumes from step 12
    assert main([*common, *fast, "--steps", "13"]) == 0
    assert load_checkpoint(out / "last.pt")["step"] == 13
    assert main(["--data", str(tmp_path / "nothing"), "--out", str(out), "--no-progress"]) == 2


@pytest.mark.sim
@pytest.mark.slow
def test_ablation_study_trains_each_variant_with_its_switch(sim_dataset, tmp_path):
    out = tmp_path / "study"
    args = ["--data", str(sim_dataset), "--out", str(out), "--config", "tiny", "--batch-size", "2"]
    assert main([*args, "--steps", "2", "--val-every", "2", "--no-progress", "--ablation-study"]) == 0
    for name in ABLATION_STUDY:
        ckpt = load_checkpoint(out / name / "last.pt")
        assert ckpt["step"] == 2
        stored = load_estimator(weights=out / name / "last.pt").config
        expected = network_config("tiny", "full" if name == NO_GEO_LOSS else name, text_dim=stored.text_dim)
        assert stored == expected, name
        lambda_geo = json.loads(ckpt["train_config"])["loss"]["lambda_geo"]
        assert lambda_geo == (0.0 if name == NO_GEO_LOSS else 10.0), name
