"""Dataset generation on a real local Ray cluster: every file byte-identical to a sequential run's; an
interrupted generation resumed with the sweep's resume file redoes only the unfinished scenes."""

from __future__ import annotations

import json

import pytest

from prompose_grasp.eval.sweep import RayExecutor, SequentialExecutor
from sim.dataset import SWEEP_FILE, DatasetConfig, generate

pytestmark = [pytest.mark.sim, pytest.mark.slow]


def _config(out):
    return DatasetConfig(out=str(out), scenes=3, frames=2, seed=4, width=96, height=72, workers=1)


def _files(root) -> dict[str, bytes]:
    """Every scene file and the split, by relative path (the resume file holds wall times: left out)."""
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != SWEEP_FILE
    }


def test_ray_dataset_is_byte_identical_and_resumes(ray_local, tmp_path):
    seq_dir, ray_dir = tmp_path / "seq", tmp_path / "ray"
    seq = generate(_config(seq_dir), progress=False, executor=SequentialExecutor())
    par = generate(_config(ray_dir), progress=False, executor=RayExecutor())
    assert seq["frames_written"] == par["frames_written"] == 6
    assert par["failed"] == [] and par["executor"].startswith("ray")
    reference = _files(seq_dir)
    assert len(reference) == 1 + 3 * 2 * 4  # split.json, 4 files per frame
    assert _files(ray_dir) == reference

    # interrupted: the last scene's line never reached the resume file and its folder is half written
    lines = (ray_dir / SWEEP_FILE).read_text().splitlines()
    last = json.loads(lines[-1])["unit"]
    (ray_dir / SWEEP_FILE).write_text("\n".join(lines[:-1]) + "\n")
    (ray_dir / last / "000001-meta.json").unlink()
    again = generate(_config(ray_dir), progress=False, resume=True, executor=RayExecutor())
    assert again["frames_written"] == 2 and again["scenes_skipped"] == 2
    assert _files(ray_dir) == reference
