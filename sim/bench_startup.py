"""Start-up benchmark: what a user waits for before the first answer, against the cost of importing torch.

    python -m sim.bench_startup --repeat 5 --json startup_bench.json [--baseline-src DIR]

Everything that is compared is measured in this one run, the cases interleaved (one of each per round, the
rounds repeated), because a shared machine's load drifts by the minute:

- `floor`: `python -c "import numpy, torch"`, the bare import cost the target is stated against;
- imports in a fresh interpreter: `prompose_grasp`, `prompose_grasp.geometry`, the estimator module;
- a cold `prompose-grasp estimate` (a fresh `python -m prompose_grasp.cli estimate` process, what the
  console script runs) on one rendered 640 x 480 frame, in three states of the user cache: `cached` (this
  prompt embedded before: the everyday case), `new prompt` (what `ProMPose.default()` stores, the prompt
  never seen: MiniLM loads), `empty cache` (the first call after installing; the fixed vocabularies come
  with the package; measured `--repeat-empty` times);
- with `--baseline-src DIR` (a checkout of an older revision), the same cold call of that code (with its
  own cache filled by one call first, and with an empty one);
- `estimate --server` (a fresh client process) against a running `prompose-grasp serve`;
- warm: the in-process `ProMPose.estimate_all` on the frame, and the service round trip of the same frame
  (PNG files and raw arrays) through `PerceptionClient`, medians over `--warm-calls`;
- load: `--parallel-requests` requests from `--clients` client threads at once: all answered? errors?
  the server's resident memory after a first round of the same load and at the end.

It lives in `sim` because it renders its frame with the MuJoCo stand-in; the library never imports `sim`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROMPT = "the blue box"


def _render_frame(folder: Path) -> dict[str, Any]:
    """The test scene (tests/perception/grounding_scene.py: a table with a can, a box, a bowl...), 640 x 480,
    written as PNG files (uint16 millimetre depth)."""
    import cv2

    sys.path.insert(0, str(ROOT / "tests" / "perception"))
    from grounding_scene import render_scene

    scene = render_scene()
    cv2.imwrite(str(folder / "rgb.png"), scene.rgb[..., ::-1])
    depth_mm = np.round(scene.depth_m * 1000).astype(np.uint16)
    cv2.imwrite(str(folder / "depth.png"), depth_mm)
    K = scene.intrinsics
    return {"rgb": folder / "rgb.png", "depth": folder / "depth.png", "K": [K.fx, K.fy, K.cx, K.cy],
            "rgb_array": scene.rgb, "depth_mm": depth_mm}  # fmt: skip


def _wall(cmd: list[str], cwd: Path, env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    run = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    wall = time.perf_counter() - t0
    if run.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({run.returncode}):\n{run.stderr[-2000:]}")
    return wall


def _estimate_cmd(frame: dict[str, Any], prompt: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "prompose_grasp.cli", "estimate", "--rgb", str(frame["rgb"]),
            "--depth", str(frame["depth"]), "--intrinsics", *map(str, frame["K"]), "--prompt", prompt,
            "--json", os.devnull, *extra]  # fmt: skip


def _start_server(env: dict[str, str], log: Path) -> tuple[subprocess.Popen, str]:
    with open(log, "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "prompose_grasp.cli", "serve", "--port", "0"],
            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err,
        )  # fmt: skip
    deadline = time.monotonic() + 300
    while True:
        text = log.read_text()
        if "listening on " in text:
            return proc, text.split("listening on ", 1)[1].split()[0]
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"the server did not come up:\n{text[-2000:]}")
        time.sleep(0.2)


def _parallel(client: Any, frame: dict[str, Any], n: int, clients: int) -> tuple[int, list[str]]:
    """`n` estimate requests spread over `clients` threads at once: (answered, error messages)."""
    answered, errors, lock = [0], [], threading.Lock()

    def worker(k: int) -> None:
        for _ in range(k):
            try:
                client.estimate_files(frame["rgb"], frame["depth"], frame["K"], PROMPT)
                with lock:
                    answered[0] += 1
            except Exception as exc:  # counted and reported: the benchmark says what failed
                with lock:
                    errors.append(" ".join(str(exc).split()))

    shares = [n // clients + (1 if i < n % clients else 0) for i in range(clients)]
    threads = [threading.Thread(target=worker, args=(k,)) for k in shares]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return answered[0], errors


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="rounds of the interleaved cold cases (default 5)")
    ap.add_argument("--repeat-empty", type=int, default=3, help="cold calls with an empty cache (default 3)")
    ap.add_argument("--warm-calls", type=int, default=10, help="warm in-process / service calls (default 10)")
    ap.add_argument(
        "--parallel-requests", type=int, default=100, help="requests of the load test (default 100)"
    )
    ap.add_argument("--clients", type=int, default=4, help="client threads of the load test (default 4)")
    ap.add_argument("--baseline-src", default=None, help="checkout of an older revision to time the same way")
    ap.add_argument("--json", dest="json_out", default=None, help="write the numbers here")
    args = ap.parse_args(argv)

    os.environ.setdefault("MUJOCO_GL", "egl")
    work = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    frame = _render_frame(work)
    base_env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}

    # Cache states. `vocab`: what `ProMPose.default()` stores (every vocabulary, no prompt); `cached`: that
    # plus this prompt, after one call.
    vocab_cache = work / "cache-vocab"
    make_vocab = [sys.executable, "-c", "from prompose_grasp import ProMPose; ProMPose.default()"]
    vocab_env = {**base_env, "PROMPOSE_GRASP_CACHE": str(vocab_cache)}
    subprocess.run(make_vocab, cwd=ROOT, env=vocab_env, check=True, timeout=900)
    warm_cache = work / "cache-warm"
    shutil.copytree(vocab_cache, warm_cache)
    warm_env = {**base_env, "PROMPOSE_GRASP_CACHE": str(warm_cache)}
    _wall(_estimate_cmd(frame, PROMPT), ROOT, warm_env)

    cases: dict[str, Any] = {
        "floor: python -c 'import numpy, torch'": lambda i: _wall(
            [sys.executable, "-c", "import numpy, torch"], ROOT, base_env),
        "import prompose_grasp": lambda i: _wall(
            [sys.executable, "-c", "import prompose_grasp"], ROOT, base_env),
        "import prompose_grasp.geometry": lambda i: _wall(
            [sys.executable, "-c", "import prompose_grasp.geometry"], ROOT, base_env),
        "import prompose_grasp.perception.estimator": lambda i: _wall(
            [sys.executable, "-c", "import prompose_grasp.perception.estimator"], ROOT, base_env),
        "cold estimate, cached prompt": lambda i: _wall(_estimate_cmd(frame, PROMPT), ROOT, warm_env),
        "cold estimate, new prompt": lambda i: _cold_new_prompt(frame, vocab_cache, work, base_env, i),
    }  # fmt: skip
    if args.baseline_src:
        base_cache = work / "cache-baseline"
        base_src = Path(args.baseline_src)
        base_run = {**base_env, "PROMPOSE_GRASP_CACHE": str(base_cache)}
        _wall(_estimate_cmd(frame, PROMPT), base_src, base_run)  # its knowledge-table cache, as a user has it
        cases["baseline: cold estimate"] = lambda i: _wall(_estimate_cmd(frame, PROMPT), base_src, base_run)
        cases["baseline: import prompose_grasp.geometry"] = lambda i: _wall(
            [sys.executable, "-c", "import prompose_grasp.geometry"], base_src, base_env)  # fmt: skip

    server, url = _start_server(warm_env, work / "serve.log")
    try:
        cases["cold estimate --server (client process)"] = lambda i: _wall(
            _estimate_cmd(frame, PROMPT, "--server", url), ROOT, warm_env)  # fmt: skip
        samples: dict[str, list[float]] = {name: [] for name in cases}
        for i in range(args.repeat):
            for name, fn in cases.items():
                samples[name].append(fn(i))
            print(f"round {i + 1}/{args.repeat} done", file=sys.stderr)
        empty = [
            _wall(
                _estimate_cmd(frame, PROMPT),
                ROOT,
                {**base_env, "PROMPOSE_GRASP_CACHE": str(work / f"empty{k}")},
            )
            for k in range(args.repeat_empty)
        ]
        samples["cold estimate, empty cache"] = empty
        if args.baseline_src:
            samples["baseline: cold estimate, empty cache"] = [
                _wall(_estimate_cmd(frame, PROMPT), Path(args.baseline_src),
                      {**base_env, "PROMPOSE_GRASP_CACHE": str(work / f"base-empty{k}")})
                for k in range(args.repeat_empty)
            ]  # fmt: skip

        warm = _warm(frame, url, warm_cache, args.warm_calls)
        load = _load(url, frame, args.parallel_requests, args.clients)
    finally:
        server.terminate()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()

    medians = {k: statistics.median(v) for k, v in samples.items()}
    floor = medians["floor: python -c 'import numpy, torch'"]
    target = 1.5 * floor + 0.5
    print(f"\nStart-up on {platform.node()} ({os.cpu_count()} cores), {args.repeat} interleaved rounds\n")
    print(f"{'case':50s} {'median s':>9s} {'min s':>7s} {'max s':>7s}  n")
    for k, v in samples.items():
        print(f"{k:50s} {statistics.median(v):9.2f} {min(v):7.2f} {max(v):7.2f}  {len(v)}")
    print(f"\ntarget for a cold estimate: 1.5 x floor + 0.5 s = {target:.2f} s")
    print(f"\n{'warm call':50s} {'median ms':>10s}")
    for k, v in warm.items():
        print(f"{k:50s} {v:10.1f}")
    print(f"\nload: {load['answered']}/{load['requests']} answered from {load['clients']} clients, "
          f"{len(load['errors'])} errors, {load['wall_s']:.1f} s; server memory "
          f"{load['rss_mb_after_first_round']:.0f} MiB after a first round of the same load, "
          f"{load['rss_mb_end']:.0f} MiB at the end")  # fmt: skip
    if args.json_out:
        doc = {
            "machine": {"node": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version()},
            "command": " ".join(
                ["python -m sim.bench_startup", *(argv if argv is not None else sys.argv[1:])]
            ),
            "samples_s": samples,
            "medians_s": medians,
            "cold_target_s": target,
            "warm_ms": warm,
            "load": load,
        }
        Path(args.json_out).write_text(json.dumps(doc, indent=2))
        print(f"wrote {args.json_out}", file=sys.stderr)
    shutil.rmtree(work, ignore_errors=True)
    return 0


def _cold_new_prompt(
    frame: dict[str, Any], vocab_cache: Path, work: Path, env: dict[str, str], i: int
) -> float:
    """A cold call whose prompt was never embedded: a fresh copy of the vocabulary-only cache each time."""
    cache = work / f"cache-new-{i}"
    shutil.copytree(vocab_cache, cache)
    try:
        return _wall(_estimate_cmd(frame, PROMPT), ROOT, {**env, "PROMPOSE_GRASP_CACHE": str(cache)})
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def _warm(frame: dict[str, Any], url: str, cache: Path, calls: int) -> dict[str, float]:
    """Medians [ms] of the in-process estimate and the service round trip on the same frame, interleaved."""
    os.environ["PROMPOSE_GRASP_CACHE"] = str(cache)
    from prompose_grasp import ProMPose
    from prompose_grasp.perception.frames_io import load_rgbd
    from prompose_grasp.service import PerceptionClient

    estimator = ProMPose.default()
    client = PerceptionClient(url)
    rgbd = load_rgbd(frame["rgb"], frame["depth"], 0.001, tuple(frame["K"]))
    estimator.estimate_all(rgbd, PROMPT)
    client.estimate_files(frame["rgb"], frame["depth"], frame["K"], PROMPT)
    local, png, raw, overhead = [], [], [], []
    for _ in range(calls):
        t0 = time.perf_counter()
        estimator.estimate_all(load_rgbd(frame["rgb"], frame["depth"], 0.001, tuple(frame["K"])), PROMPT)
        local.append(1e3 * (time.perf_counter() - t0))
        t0 = time.perf_counter()
        doc = client.estimate_files(frame["rgb"], frame["depth"], frame["K"], PROMPT)
        png.append(1e3 * (time.perf_counter() - t0))
        # what the service adds around the same estimator call: the round trip less the server's own
        # `timing_ms.total` (PNG decoding, JSON, HTTP, the queue); much less noisy on a loaded machine than
        # the difference of two estimates
        overhead.append(png[-1] - doc["timing_ms"]["total"])
        t0 = time.perf_counter()
        client.estimate(frame["rgb_array"], frame["depth_mm"], frame["K"], PROMPT)
        raw.append(1e3 * (time.perf_counter() - t0))
    out = {
        "in-process: read PNGs + estimate_all": statistics.median(local),
        "service round trip, PNG files": statistics.median(png),
        "service round trip, raw arrays": statistics.median(raw),
    }
    out["service PNG - in-process"] = (
        out["service round trip, PNG files"] - out["in-process: read PNGs + estimate_all"]
    )
    out["service round trip - server's estimate total"] = statistics.median(overhead)
    return out


def _load(url: str, frame: dict[str, Any], n: int, clients: int) -> dict[str, Any]:
    from prompose_grasp.service import PerceptionClient

    client = PerceptionClient(url, timeout_s=600)
    _parallel(client, frame, n, clients)  # first round: sets the peak of `clients` frames in flight
    middle = client.health()
    t0 = time.perf_counter()
    answered, errors = _parallel(client, frame, n, clients)
    wall = time.perf_counter() - t0
    end = client.health()
    return {"requests": n, "clients": clients, "answered": answered, "errors": errors[:5], "wall_s": wall,
            "rss_mb_after_first_round": middle["rss_mb"], "rss_mb_end": end["rss_mb"]}  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
