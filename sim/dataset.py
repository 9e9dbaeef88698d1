"""Synthetic RGB-D dataset generator (CAMERA25-like scenes, moving camera): DESIGN.md "Synthetic dataset".

    python -m sim.dataset --out DIR --scenes N --frames M --seed S [--workers 2] [--noise realsense]
                          [--ray local:N|auto|HOST:PORT] [--resume]

Each scene: a table with a random size, texture and lighting; 3 to 6 procedural objects standing close
together (so they occlude each other) with random shapes and materials; a camera that orbits the group over
the frames (azimuth sweep of 20-60 degrees, drifting elevation and distance) so a sequence serves the temporal
model.

Layout::

    DIR/split.json                       train/val/test scene lists and the categories of each split
    DIR/<scene>/<frame:06d>-color.png    RGB, 8 bit
    DIR/<scene>/<frame:06d>-depth.png    uint16 millimetres (0 = no reading), after the sensor noise model
    DIR/<scene>/<frame:06d>-mask.png     instance ids (uint8; 0 = background), matching objects[].id
    DIR/<scene>/<frame:06d>-meta.json    K, T_world_cam, objects [{id, category, prompt, mesh, R, t, size,
                                         symmetry, visible_px[, handle_px, handle_visible]}], all 9-DoF in
                                         the OpenCV camera frame

Mug handle visibility (the NOCS protocol's `gt_handle_visibility`: a mug whose handle is not seen counts as
symmetric about its axis): `handle_px` is the number of pixels where the handle's own visual geom is the
front-most surface (a geom-level segmentation render, so occlusion by the mug body or other objects counts),
and `handle_visible` is `handle_px >= HANDLE_VISIBLE_MIN_PX` (20: a handle seen edge-on or through a gap
of a few pixels cannot fix the yaw). Only mugs carry the two fields.

Default split (zero-shot protocol): test categories mug, bottle, laptop, camera are never in train or val
scenes; train/val use box, carton, can, bowl, cup, ball, tube, sack, parcel. Test scenes hold 2-4
test-category objects and 1-2 train-category distractors (annotated too; their category tells them apart).
20 % of the scenes (at least one) are test, 10 % val, the rest train, chosen by the seed.

Deterministic: scene i draws everything from `numpy.random.default_rng([seed, i])`, so the output does not
depend on the worker count or on resuming. Resumable: a scene whose last meta file exists is skipped.

`--ray` runs each scene as a Ray task of one CPU (`prompose_grasp.eval.sweep`, extra `cluster`; docs/scale.md)
instead of the local process pool: the files are byte-identical to a sequential run's. With `--ray` or
`--resume`, DIR/sweep.jsonl records each finished scene as it ends; `--resume` skips those, and a scene that
failed after its retries is listed in the summary (`failed`) with its error type.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError, MissingDependencyError, UnknownNameError

__all__ = [
    "DEFAULT_TEST_CATEGORIES",
    "DEFAULT_TRAIN_CATEGORIES",
    "HANDLE_VISIBLE_MIN_PX",
    "DatasetConfig",
    "generate",
    "make_split",
]

log = logging.getLogger(__name__)

DEFAULT_TRAIN_CATEGORIES = ("box", "carton", "can", "bowl", "cup", "ball", "tube", "sack", "parcel")
DEFAULT_TEST_CATEGORIES = ("mug", "bottle", "laptop", "camera")

#: A mug's handle counts as visible (meta `handle_visible`) when at least this many pixels of it are seen.
HANDLE_VISIBLE_MIN_PX = 20

#: Size limits that keep large families (carton, sack, tube, laptop) tabletop-sized in household scenes.
_TABLETOP_PARAMS = {
    "carton": {"width_m": (0.2, 0.3), "height_m": (0.12, 0.22), "depth_m": (0.15, 0.25)},
    "sack": {"length_m": (0.2, 0.3), "width_m": (0.14, 0.2), "thickness_m": (0.05, 0.09)},
    "tube": {"length_m": (0.15, 0.28)},
    "parcel": {"length_m": (0.15, 0.28), "width_m": (0.1, 0.2), "height_m": (0.06, 0.14)},
    "laptop": {"width_m": (0.28, 0.34), "depth_m": (0.19, 0.23)},
}


@dataclass(frozen=True)
class DatasetConfig:
    """Generator settings. Sizes in pixels, lengths in metres."""

    out: str
    scenes: int = 20
    frames: int = 8
    seed: int = 0
    width: int = 640
    height: int = 480
    fovy_deg: float = 58.0
    noise: str = "realsense"
    workers: int = 2
    train_categories: tuple[str, ...] = DEFAULT_TRAIN_CATEGORIES
    test_categories: tuple[str, ...] = DEFAULT_TEST_CATEGORIES

    def __post_init__(self) -> None:
        from sim.noise import noise_preset
        from sim.objects import FAMILIES

        if self.scenes < 1 or self.frames < 1 or self.workers < 1:
            raise InvalidInputError(
                f"scenes, frames and workers must be >= 1, got {self.scenes}, {self.frames}, {self.workers}"
            )
        noise_preset(self.noise)
        for c in (*self.train_categories, *self.test_categories):
            if c not in FAMILIES:
                raise UnknownNameError("category", c, sorted(FAMILIES))
        overlap = set(self.train_categories) & set(self.test_categories)
        if overlap:
            raise InvalidInputError(
                f"train and test categories must be disjoint; both hold {sorted(overlap)}"
            )


def scene_name(i: int) -> str:
    return f"scene_{i:05d}"


def make_split(config: DatasetConfig) -> dict:
    """The split.json document: scene names per split and categories per split (deterministic by seed)."""
    n = config.scenes
    order = np.random.default_rng([config.seed, 2**31 - 1]).permutation(n)
    n_test = max(1, round(0.2 * n)) if n >= 2 else 0
    n_val = round(0.1 * n) if n - n_test >= 2 else 0
    test = sorted(int(i) for i in order[:n_test])
    val = sorted(int(i) for i in order[n_test : n_test + n_val])
    train = sorted(int(i) for i in order[n_test + n_val :])
    return {
        "version": 1,
        "seed": config.seed,
        "train": {"scenes": [scene_name(i) for i in train], "categories": list(config.train_categories)},
        "val": {"scenes": [scene_name(i) for i in val], "categories": list(config.train_categories)},
        "test": {
            "scenes": [scene_name(i) for i in test],
            "categories": list(config.test_categories),
            "distractor_categories": list(config.train_categories),
        },
        "config": asdict(config) | {"out": None},
    }


def _scene_categories(rng: np.random.Generator, is_test: bool, config: DatasetConfig) -> list[str]:
    if is_test:
        main = list(rng.choice(config.test_categories, size=int(rng.integers(2, 5)), replace=True))
        distractors = list(rng.choice(config.train_categories, size=int(rng.integers(1, 3)), replace=True))
        return [str(c) for c in main + distractors]
    return [str(c) for c in rng.choice(config.train_categories, size=int(rng.integers(3, 7)), replace=True)]


def _object_params(family: str, rng: np.random.Generator) -> dict:
    from sim.objects import FAMILIES

    limits = _TABLETOP_PARAMS.get(family, {})
    params = {}
    for key, (lo, hi) in FAMILIES[family].ranges.items():
        lo2, hi2 = limits.get(key, (lo, hi))
        params[key] = (
            int(rng.integers(int(lo2), int(hi2)))
            if key in FAMILIES[family].integer_params
            else float(rng.uniform(lo2, hi2))
        )
    return params


def _camera_path(rng: np.random.Generator, target: np.ndarray, frames: int) -> list[np.ndarray]:
    """T_world_cam per frame: an orbit around `target` with drifting elevation and distance."""
    from sim.camera import look_at

    az0 = rng.uniform(-math.pi, math.pi)
    sweep = math.radians(rng.uniform(20.0, 60.0)) * rng.choice([-1.0, 1.0])
    el0, el1 = np.radians(rng.uniform(30.0, 65.0, size=2))
    d0, d1 = rng.uniform(0.55, 1.0, size=2)
    jitter = rng.normal(0.0, 0.02, size=3)
    poses = []
    for k in range(frames):
        s = k / max(frames - 1, 1)
        az, el, dist = az0 + sweep * s, el0 + (el1 - el0) * s, d0 + (d1 - d0) * s
        eye = target + dist * np.array(
            [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
        )
        poses.append(look_at(eye, target + jitter * (1.0 - 0.5 * s)))
    return poses


def _build_scene(rng: np.random.Generator, categories: Sequence[str], config: DatasetConfig):
    """Build a settled world and the metadata of its objects."""
    from sim.appearance import random_appearance
    from sim.camera import CameraSpec
    from sim.noise import noise_preset
    from sim.objects import make_object
    from sim.placement import footprint_radius_m, sample_upright_placements
    from sim.scene_builder import SceneBuilder

    b = SceneBuilder("dataset_scene")  # the default sensor look (no MSAA, 1024 px shadows)
    b.add_floor()
    b.add_skybox(top_rgb=tuple(rng.uniform(0.4, 0.9, 3)), bottom_rgb=tuple(rng.uniform(0.05, 0.3, 3)))
    size = (float(rng.uniform(1.0, 1.6)), float(rng.uniform(0.7, 1.0)))
    table = b.add_table(
        size_xy_m=size, height_m=float(rng.uniform(0.7, 0.8)), appearance=random_appearance(rng, "table")
    )
    for _ in range(int(rng.integers(1, 4))):
        pos = [rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(1.8, 3.0)]
        b.add_light(
            pos,
            [-pos[0] * 0.3, -pos[1] * 0.3, -1.0],
            float(rng.uniform(0.25, 0.7)),
            castshadow=bool(rng.random() < 0.7),
        )
    b.set_headlight(float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.1, 0.4)))
    assets = [make_object(c, _object_params(c, rng)) for c in categories]
    # A crowded patch, so objects occlude each other; it grows towards the table's size until all fit.
    r_max = max(footprint_radius_m(a) for a in assets)
    table_half = table.half_extents_xy_m - 0.03
    half = np.minimum(np.maximum(np.array([0.28, 0.2]), r_max + 0.06), table_half)
    while True:
        try:
            poses = sample_upright_placements(
                assets,
                table,
                rng,
                margin_m=0.005,
                region_half_extents_m=half,
                clearance_m=0.001,
                max_tries=300,
            )
            break
        except InvalidInputError:
            if np.all(half >= table_half):
                assets = assets[:-1]  # too many for this table: drop one object and retry
                if not assets:
                    raise
            half = np.minimum(half * 1.25, table_half)
    for i, (asset, T) in enumerate(zip(assets, poses)):
        b.add_object(
            asset, f"{asset.category}_{i}", T, prompt=asset.category, appearance=random_appearance(rng)
        )
    b.add_camera(
        CameraSpec("cam", config.width, config.height, config.fovy_deg, noise=noise_preset(config.noise))
    )
    world = b.build()
    world.settle(max_steps=1500)
    target = table.T_world_surface[:3, 3] + np.array([0.0, 0.0, 0.05])
    return world, target


def _geom_segmentation(world, camera: str, renderer) -> np.ndarray:
    """(H, W) int32 geom ids of the front-most surface per pixel (-1 = none): a segmentation render."""
    import mujoco

    renderer.update_scene(world.data, camera=camera)
    renderer.enable_segmentation_rendering()
    try:
        seg = renderer.render()
    finally:
        renderer.disable_segmentation_rendering()
    ids, types = seg[..., 0], seg[..., 1]
    return np.where(types == int(mujoco.mjtObj.mjOBJ_GEOM), ids, -1).astype(np.int32)


def _handle_geoms(world) -> dict[int, int]:
    """instance id -> visual geom id of the handle, for each mug (its parts are [body, handle], see
    `sim.objects`)."""
    out = {}
    for o in world.objects:
        if o.category == "mug" and len(o.visual_geom_ids) >= 2:
            out[o.instance_id] = int(o.visual_geom_ids[1])
    return out


def _write_png(path: Path, image: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), image):
        raise InvalidInputError(f"could not write {path}")


def generate_scene(index: int, config: DatasetConfig, is_test: bool) -> int:
    """Generate one scene (all frames); returns the number of frames written (0 when already complete)."""
    out = Path(config.out) / scene_name(index)
    if (out / f"{config.frames - 1:06d}-meta.json").is_file():
        return 0
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([config.seed, index])
    categories = _scene_categories(rng, is_test, config)
    world, target = _build_scene(rng, categories, config)
    handles = _handle_geoms(world)
    seg_renderer = None
    with world:
        for k, T_world_cam in enumerate(_camera_path(rng, target, config.frames)):
            world.set_camera_pose("cam", T_world_cam)
            frame = world.render("cam", rng=rng)
            mask = world.ground_truth_mask("cam")
            gts = world.ground_truth("cam")
            geoms = None
            if handles:
                if seg_renderer is None:
                    import mujoco

                    seg_renderer = mujoco.Renderer(world.model, height=config.height, width=config.width)
                geoms = _geom_segmentation(world, "cam", seg_renderer)
            depth_mm = np.clip(np.rint(frame.depth_m * 1000.0), 0, 65535).astype(np.uint16)
            stem = out / f"{k:06d}"
            _write_png(Path(f"{stem}-color.png"), frame.rgb[..., ::-1])
            _write_png(Path(f"{stem}-depth.png"), depth_mm)
            _write_png(Path(f"{stem}-mask.png"), mask.astype(np.uint8))
            objects = []
            for g in gts:
                family = g.source.split(":", 1)[1] if g.source.startswith("procedural:") else None
                mesh = {"family": family, "params": g.params} if family else {"path": g.source}
                entry = {
                    "id": g.instance_id,
                    "name": g.name,
                    "category": g.category,
                    "prompt": g.prompt,
                    "mesh": mesh,
                    "R": g.R_cam_obj.tolist(),
                    "t": g.t_cam_obj_m.tolist(),
                    "size": g.size_m.tolist(),
                    "symmetry": g.symmetry,
                    "visible_px": int(np.count_nonzero(mask == g.instance_id)),
                }
                if geoms is not None and g.instance_id in handles:
                    handle_px = int(np.count_nonzero(geoms == handles[g.instance_id]))
                    entry["handle_px"] = handle_px
                    entry["handle_visible"] = handle_px >= HANDLE_VISIBLE_MIN_PX
                objects.append(entry)
            meta = {
                "scene": scene_name(index),
                "frame": k,
                "width": config.width,
                "height": config.height,
                "K": frame.intrinsics.K.tolist(),
                "depth_scale_m": 0.001,
                "noise": config.noise,
                "T_world_cam": world.T_world_cam("cam").tolist(),
                "objects": objects,
            }
            tmp = Path(f"{stem}-meta.json.tmp")
            tmp.write_text(json.dumps(meta, indent=1))
            tmp.replace(Path(f"{stem}-meta.json"))  # the meta file appears only when the frame is complete
    if seg_renderer is not None:
        seg_renderer.close()
    return config.frames


def _worker(args: tuple[int, DatasetConfig, bool]) -> tuple[int, int]:
    index, config, is_test = args
    return index, generate_scene(index, config, is_test)


def scene_unit(payload: tuple[int, DatasetConfig, bool]) -> dict:
    """One scene as a sweep unit (`prompose_grasp.eval.sweep`): {"scene", "frames_written"}."""
    index, config, is_test = payload
    return {"scene": scene_name(index), "frames_written": generate_scene(index, config, is_test)}


#: The resume file of a sweep-run generation (`--ray` / `--resume`), in the output folder.
SWEEP_FILE = "sweep.jsonl"


def generate(
    config: DatasetConfig,
    progress: bool = True,
    ray: str | None = None,
    resume: bool = False,
    retries: int = 2,
    executor: Any = None,
) -> dict:
    """Generate the dataset; returns {"frames_written", "scenes_skipped", "seconds", "frames_per_second"}
    (and, through the sweep: "failed" rows and "scene_wall_s" per scene).

    `ray` (a `--ray` value), `executor` (a `prompose_grasp.eval.sweep` executor) or `resume` run the scenes
    through the sweep with DIR/sweep.jsonl as its resume file; otherwise `config.workers` local processes."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    split = make_split(config)
    (out / "split.json").write_text(json.dumps(split, indent=1))
    test = set(split["test"]["scenes"])
    jobs = [(i, config, scene_name(i) in test) for i in range(config.scenes)]
    if ray is not None or executor is not None or resume:
        return _generate_sweep(jobs, out, progress, ray, resume, retries, executor)
    t0 = time.perf_counter()
    written = skipped = 0
    bar = None
    if progress:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        bar = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn(), TimeRemainingColumn())  # fmt: skip
        bar.start()
        task = bar.add_task("scenes", total=len(jobs))
    try:
        if config.workers == 1:
            results = map(_worker, jobs)
            pool = None
        else:
            # spawn: each worker starts clean and opens its own EGL context (no GL state crosses a fork)
            pool = mp.get_context("spawn").Pool(config.workers)
            results = pool.imap_unordered(_worker, jobs)
        for _, n in results:
            written += n
            skipped += n == 0
            if bar is not None:
                bar.advance(task)
        if pool is not None:
            pool.close()
            pool.join()
    finally:
        if bar is not None:
            bar.stop()
    seconds = time.perf_counter() - t0
    return {
        "frames_written": written,
        "scenes_skipped": skipped,
        "seconds": seconds,
        "frames_per_second": written / seconds if seconds > 0 else 0.0,
    }


def _generate_sweep(jobs, out: Path, progress: bool, ray, resume: bool, retries: int, executor) -> dict:
    from prompose_grasp.eval.sweep import Unit, make_executor, run_sweep

    executor = executor or make_executor(ray)
    units = [Unit(scene_name(job[0]), job) for job in jobs]
    sweep = run_sweep(
        scene_unit,
        units,
        executor=executor,
        num_cpus=1,
        retries=retries,
        resume_file=out / SWEEP_FILE,
        resume=resume,
        progress=progress,
        label="scenes",
    )
    ran = [r for uid, r in sweep.results.items() if uid not in sweep.resumed]  # resumed: written before
    written = sum(int(r["frames_written"]) for r in ran)
    skipped = sum(int(r["frames_written"]) == 0 for r in ran) + len(sweep.resumed)
    return {
        "frames_written": written,
        "scenes_skipped": skipped,
        "seconds": sweep.wall_s,
        "frames_per_second": written / sweep.wall_s if sweep.wall_s > 0 else 0.0,
        "failed": [f.as_row() for f in sweep.failures.values()],
        "scene_wall_s": sweep.unit_wall_s,
        "executor": sweep.executor,
    }


def _check_sweep_args(ray: str | None, retries: int) -> None:
    if ray is not None:
        from prompose_grasp.eval.sweep import parse_ray_address

        parse_ray_address(ray)
    if retries < 0:
        raise InvalidInputError(f"--retries must be >= 0, got {retries}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.dataset", description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--scenes", type=int, default=20, help="number of scenes (default 20)")
    parser.add_argument("--frames", type=int, default=8, help="frames per scene (default 8)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--fovy-deg", type=float, default=58.0)
    parser.add_argument("--noise", default="realsense", help="clean | realsense | kinect")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument(
        "--ray", default=None, metavar="ADDRESS",
        help="run the scenes as Ray tasks: local:N (a local cluster of N CPUs), auto (the cluster of "
        "`ray start`), or HOST:PORT (extra `cluster`; --workers is then unused)",
    )  # fmt: skip
    parser.add_argument("--resume", action="store_true", help="skip the scenes OUT/sweep.jsonl lists as done")
    parser.add_argument("--retries", type=int, default=2, help="attempts after the first for a failed scene")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = DatasetConfig(
            out=args.out, scenes=args.scenes, frames=args.frames, seed=args.seed, width=args.width,
            height=args.height, fovy_deg=args.fovy_deg, noise=args.noise, workers=args.workers,
        )  # fmt: skip
        _check_sweep_args(args.ray, args.retries)  # before anything is written
        stats = generate(
            config, progress=not args.no_progress, ray=args.ray, resume=args.resume, retries=args.retries
        )
    except (InvalidInputError, UnknownNameError, MissingDependencyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{stats['frames_written']} frames in {stats['seconds']:.1f} s "
        f"({stats['frames_per_second']:.2f} frames/s), "
        f"{stats['scenes_skipped']} scenes already complete; split: {Path(args.out) / 'split.json'}"
    )
    for row in stats.get("failed", []):
        print(f"FAILED {row['unit']}: {row['error']} after {row['attempts']} attempts: {row['message']}")
    return 1 if stats.get("failed") else 0


if __name__ == "__main__":
    # run the module's own copy, so that the units Ray pickles name `sim.dataset`, not `__main__`
    from sim.dataset import main as _main

    sys.exit(_main())
