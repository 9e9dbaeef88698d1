"""Fan-out of independent units of work (a dataset scene, a bench episode, a scene of frames) over one
process or a Ray cluster, with results identical to a sequential run.

    sweep = run_sweep(scene_unit, [Unit("scene_00000", (0, config, False)), ...],   # sim.dataset's unit
                      executor=make_executor("local:2"), resume_file=out / "sweep.jsonl", resume=True)
    sweep.results["scene_00000"]          # the unit's result (JSON value), or
    sweep.failures["scene_00003"]         # its UnitFailure after the retries

Contract of a unit function `fn(payload) -> JSON value`: it draws every random number from the unit's own seed
(carried in the payload), never from the worker's or the driver's state, so a unit's result does not depend on
which worker runs it, on what that worker ran before, or on the order units finish in. Results are ordered by
the units' order as given, never by finish order, and pass through one JSON round trip in every executor (what
the resume file stores is exactly what a fresh run returns).

Executors (same interface, `Executor`):

- `SequentialExecutor`: one unit after the other in this process; an exception is retried in place.
- `RayExecutor` (extra `cluster`): each unit is a Ray task declaring `num_cpus`; the driver keeps at most as
  many tasks in flight as the cluster has slots, so the progress bar's "running" is what runs. A task that
  raises, or whose worker process dies (killed, out of memory, a segfault in a native library), is submitted
  again up to `retries` times, then reported as that unit's `UnitFailure` ("worker_died" or the exception's
  type) while the other units go on.

Threads: a unit runs with OpenMP / MKL / OpenBLAS / llvmpipe / torch threads pinned to its `num_cpus` (in
both executors, so the float reduction order inside a unit is the same either way), and MuJoCo renders
through EGL (`MUJOCO_GL=egl`).

Resume file (JSONL, one line per finished unit, appended and flushed as each unit ends): a sweep that is
interrupted loses only the units in flight; with `resume=True` the units with a result line are not run again
(failed units are). Without `resume`, the file is started afresh.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

from prompose_grasp.errors import InvalidInputError

__all__ = [
    "THREAD_ENV_VARS",
    "Executor",
    "RayExecutor",
    "SequentialExecutor",
    "SweepResult",
    "Unit",
    "UnitFailure",
    "make_executor",
    "parse_ray_address",
    "read_resume_file",
    "run_sweep",
]

log = logging.getLogger(__name__)

#: Environment variables that size the thread pools of the native libraries a unit may load (OpenMP, MKL,
#: OpenBLAS, Mesa's llvmpipe rasteriser for CPU rendering); set to the unit's num_cpus so that a node running
#: one task per CPU is not oversubscribed.
THREAD_ENV_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "LP_NUM_THREADS")

#: The failure type of a unit whose worker process ended without an answer (SIGKILL, OOM killer, a crash).
WORKER_DIED = "worker_died"


@dataclass(frozen=True)
class Unit:
    """One independent piece of a sweep: `id` names it in results and the resume file (unique within the
    sweep); `payload` is the unit function's argument (picklable; it carries the unit's seed)."""

    id: str
    payload: Any


@dataclass(frozen=True)
class UnitFailure:
    """A unit that did not finish after its attempts: `error` is the exception's type name, or
    "worker_died" when the process running it ended; `message` the first 300 characters of what it said."""

    unit: str
    error: str
    message: str
    attempts: int

    def as_row(self) -> dict[str, Any]:
        return {"unit": self.unit, "failed": True, **asdict(self)}


@dataclass(frozen=True)
class SweepResult:
    """What a sweep produced, keyed by unit id in the units' order.

    Attributes:
        results: unit id -> result (a JSON value), for every finished unit (also the resumed ones).
        failures: unit id -> UnitFailure.
        resumed: ids of the units taken from the resume file instead of run.
        unit_wall_s: unit id -> seconds of its last attempt, measured inside the worker (resumed units keep
            the time of the run that made them).
        wall_s: seconds the sweep took on the driver (start-up of the executor included).
        executor: `describe()` of the executor.
    """

    results: dict[str, Any]
    failures: dict[str, UnitFailure]
    resumed: tuple[str, ...]
    unit_wall_s: dict[str, float]
    wall_s: float
    executor: str
    order: tuple[str, ...] = field(default=())

    def rows(self) -> list[tuple[str, Any | UnitFailure]]:
        """(unit id, result or UnitFailure) for every unit run or resumed, in the units' order."""
        return [
            (u, self.results[u] if u in self.results else self.failures[u])
            for u in self.order
            if u in self.results or u in self.failures
        ]


@dataclass(frozen=True)
class _Outcome:
    unit: str
    ok: bool
    result: Any = None
    failure: UnitFailure | None = None
    wall_s: float = 0.0


class Executor(Protocol):
    """Runs unit functions; yields one `_Outcome` per unit as each ends (in any order)."""

    def describe(self) -> str: ...

    def slots(self, num_cpus: float) -> int: ...

    def run(
        self,
        fn: Callable[[Any], Any],
        units: Sequence[Unit],
        num_cpus: float,
        retries: int,
        on_running: Callable[[int], None],
    ) -> Iterator[_Outcome]: ...


def _pin_threads(num_cpus: float) -> dict[str, str | None]:
    """Pin the native thread pools to `num_cpus` (at least 1); returns the previous environment values."""
    n = max(1, int(num_cpus))
    before = {k: os.environ.get(k) for k in THREAD_ENV_VARS}
    for k in THREAD_ENV_VARS:
        os.environ[k] = str(n)
    os.environ.setdefault("MUJOCO_GL", "egl")
    torch = sys.modules.get("torch")  # a unit that imports torch later reads OMP_NUM_THREADS at import
    if torch is not None:
        torch.set_num_threads(n)
    return before


def _restore_threads(before: dict[str, str | None], torch_threads: int | None) -> None:
    for k, v in before.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    torch = sys.modules.get("torch")
    if torch is not None and torch_threads is not None:
        torch.set_num_threads(torch_threads)


def _json_round_trip(value: Any) -> Any:
    """The value as the resume file stores it, so a fresh and a resumed sweep return the same objects."""
    return json.loads(json.dumps(value))


def _call_unit(fn: Callable[[Any], Any], payload: Any, num_cpus: float) -> tuple[Any, float]:
    """Run one unit with pinned threads: (its result after a JSON round trip, seconds)."""
    torch = sys.modules.get("torch")
    torch_threads = torch.get_num_threads() if torch is not None else None
    before = _pin_threads(num_cpus)
    try:
        t0 = time.perf_counter()
        result = _json_round_trip(fn(payload))
        return result, time.perf_counter() - t0
    finally:
        _restore_threads(before, torch_threads)


def _failure(unit: str, exc: BaseException, attempts: int) -> UnitFailure:
    return UnitFailure(unit, type(exc).__name__, str(exc)[:300], attempts)


class SequentialExecutor:
    """One unit after the other in this process (the reference every other executor must match)."""

    def describe(self) -> str:
        return "sequential"

    def slots(self, num_cpus: float) -> int:
        return 1

    def run(
        self,
        fn: Callable[[Any], Any],
        units: Sequence[Unit],
        num_cpus: float,
        retries: int,
        on_running: Callable[[int], None],
    ) -> Iterator[_Outcome]:
        for unit in units:
            on_running(1)
            for attempt in range(1, retries + 2):
                try:
                    result, wall = _call_unit(fn, unit.payload, num_cpus)
                except Exception as exc:  # a unit's own error: retried, then its typed failure row
                    log.warning(
                        "unit %s attempt %d failed: %s: %s", unit.id, attempt, type(exc).__name__, exc
                    )
                    if attempt > retries:
                        yield _Outcome(unit.id, False, failure=_failure(unit.id, exc, attempt))
                    continue
                yield _Outcome(unit.id, True, result=result, wall_s=wall)
                break
            on_running(0)


def parse_ray_address(spec: str) -> dict[str, Any]:
    """`ray.init` keyword arguments of a `--ray` value: "local:N" (start a local cluster of N CPUs),
    "auto" (join the cluster this node belongs to, after `ray start`), or an address ("HOST:PORT",
    "ray://HOST:10001")."""
    spec = spec.strip()
    if not spec:
        raise InvalidInputError("--ray needs a value: local:N, auto, or a cluster address (HOST:PORT)")
    if spec.startswith("local"):
        _, _, n = spec.partition(":")
        try:
            cpus = int(n) if n else (os.cpu_count() or 1)
        except ValueError:
            raise InvalidInputError(f"--ray {spec!r}: local:N takes a CPU count, e.g. local:2") from None
        if cpus < 1:
            raise InvalidInputError(f"--ray {spec!r}: a local cluster needs at least 1 CPU")
        return {"num_cpus": cpus}
    return {"address": spec}


def _library_root() -> str:
    return str(Path(__file__).resolve().parents[2])


def _worker_env(num_cpus: float, roots: Sequence[str]) -> dict[str, str]:
    """A worker's environment variables: thread pools pinned to `num_cpus`, MuJoCo on EGL, and `roots` (then
    this process's PYTHONPATH) on the import path."""
    n = str(max(1, int(num_cpus)))
    env = {k: n for k in THREAD_ENV_VARS}
    paths = [*roots, *filter(None, [os.environ.get("PYTHONPATH")])]
    env.update(MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONPATH=os.pathsep.join(paths))
    return env


def _code_roots(fn: Callable[[Any], Any]) -> list[str]:
    """Folders that make the unit function's module and this library importable on a worker (the
    top-level packages' parents), for the workers' PYTHONPATH."""
    roots = []
    for name in (fn.__module__, __name__):
        top = sys.modules[name.split(".")[0]]
        path = getattr(top, "__file__", None)
        if path:
            file = Path(path).resolve()
            root = str(file.parent.parent if file.name == "__init__.py" else file.parent)
            if root not in roots:
                roots.append(root)
    return roots


class RayExecutor:
    """Units as Ray tasks on a cluster (`ray.init(**parse_ray_address(spec))`, or the cluster this process
    already joined). Retries are the driver's: a failed attempt is submitted again, so the attempt count is
    known and a unit that keeps failing ends as a `UnitFailure` without stopping the others."""

    def __init__(self, spec: str | None = None):
        from prompose_grasp._optional import require

        self.ray = require("ray", extra="cluster")
        self.spec = spec
        #: the environment every worker of this job starts with (None: a cluster this process did not join)
        self.job_env: dict[str, str] | None = None
        if not self.ray.is_initialized():
            kwargs = parse_ray_address(spec or "auto")
            # Job-wide worker environment for one-CPU units, so that workers need not be started anew for a
            # per-task environment (a task whose environment differs still gets its own, `run`).
            self.job_env = _worker_env(1, [_library_root(), os.getcwd()])
            self.ray.init(
                **kwargs,
                runtime_env={"env_vars": self.job_env},
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.WARNING,
            )

    def describe(self) -> str:
        cpus = self.ray.cluster_resources().get("CPU", 0)
        return f"ray ({self.spec or 'existing'}, {cpus:g} CPUs)"

    def slots(self, num_cpus: float) -> int:
        cpus = float(self.ray.cluster_resources().get("CPU", 1))
        return max(1, int(cpus // max(num_cpus, 1e-3)))

    def run(
        self,
        fn: Callable[[Any], Any],
        units: Sequence[Unit],
        num_cpus: float,
        retries: int,
        on_running: Callable[[int], None],
    ) -> Iterator[_Outcome]:
        ray = self.ray
        options: dict[str, Any] = {}
        job = self.job_env
        roots = _code_roots(fn)
        known = set(job["PYTHONPATH"].split(os.pathsep)) if job is not None else set()
        if job is None or max(1, int(num_cpus)) != int(job["OMP_NUM_THREADS"]) or not set(roots) <= known:
            options["runtime_env"] = {"env_vars": _worker_env(num_cpus, roots)}
        # Retries by the driver (max_retries=0 for Ray itself), so each unit's attempts are counted here.
        task = ray.remote(_call_unit).options(
            num_cpus=num_cpus, max_retries=0, retry_exceptions=False, **options
        )
        fn_ref = ray.put(fn)
        todo = list(units)[::-1]  # popped from the end: submitted in the units' order
        attempts: dict[str, int] = {}
        in_flight: dict[Any, Unit] = {}
        slots = self.slots(num_cpus)
        while todo or in_flight:
            while todo and len(in_flight) < slots:
                unit = todo.pop()
                attempts[unit.id] = attempts.get(unit.id, 0) + 1
                in_flight[task.remote(fn_ref, unit.payload, num_cpus)] = unit
            on_running(len(in_flight))
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                unit = in_flight.pop(ref)
                try:
                    result, wall = ray.get(ref)
                except Exception as exc:
                    failure = self._failure(unit.id, exc, attempts[unit.id])
                    log.warning("unit %s attempt %d failed: %s", unit.id, attempts[unit.id], failure.error)
                    if attempts[unit.id] <= retries:
                        todo.append(unit)  # next in line, ahead of the units not yet started
                    else:
                        yield _Outcome(unit.id, False, failure=failure)
                    continue
                yield _Outcome(unit.id, True, result=result, wall_s=wall)
        on_running(0)

    def _failure(self, unit: str, exc: BaseException, attempts: int) -> UnitFailure:
        errors = self.ray.exceptions
        dead = (errors.WorkerCrashedError, errors.NodeDiedError, errors.LocalRayletDiedError)
        oom = getattr(errors, "OutOfMemoryError", ())
        if isinstance(exc, dead) or (oom and isinstance(exc, oom)):
            return UnitFailure(unit, WORKER_DIED, str(exc).splitlines()[0][:300], attempts)
        if isinstance(exc, errors.RayTaskError):
            cause = exc.cause if getattr(exc, "cause", None) is not None else exc
            name = type(cause).__name__
            # a RayTaskError's class is a subclass named after the cause ("RayTaskError(KeyError)")
            return UnitFailure(
                unit, name.removeprefix("RayTaskError(").rstrip(")"), str(cause)[:300], attempts
            )
        return _failure(unit, exc, attempts)


def make_executor(ray: str | None) -> SequentialExecutor | RayExecutor:
    """The executor of a `--ray` option: None -> sequential (Ray is not imported)."""
    return SequentialExecutor() if ray is None else RayExecutor(ray)


def read_resume_file(path: str | Path) -> dict[str, dict[str, Any]]:
    """unit id -> its last line in a resume file (a truncated last line, from a killed driver, is skipped)."""
    out: dict[str, dict[str, Any]] = {}
    p = Path(path)
    if not p.is_file():
        return out
    for line in p.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(entry, dict) and "unit" in entry:
            out[str(entry["unit"])] = entry
    return out


class _Progress:
    """One bar for the whole sweep on the driver: units done / failed / running."""

    def __init__(self, enabled: bool, label: str, total: int, done: int):
        self.bar = None
        self.done, self.failed, self.running = done, 0, 0
        if enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(
                TextColumn(label), BarColumn(), MofNCompleteColumn(),
                TextColumn("failed {task.fields[failed]}  running {task.fields[running]}"),
                TimeElapsedColumn(),
            )  # fmt: skip
            self.task = self.bar.add_task(label, total=total, completed=done, failed=0, running=0)
            self.bar.start()

    def update(self) -> None:
        if self.bar is not None:
            self.bar.update(
                self.task, completed=self.done + self.failed, failed=self.failed, running=self.running
            )

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def run_sweep(
    fn: Callable[[Any], Any],
    units: Sequence[Unit],
    *,
    executor: Executor | None = None,
    num_cpus: float = 1,
    retries: int = 2,
    resume_file: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    label: str = "units",
) -> SweepResult:
    """Run `fn(unit.payload)` for every unit (see the module docstring).

    Args:
        fn: a module-level function (workers import it by name) returning a JSON value.
        units: unique ids; the results keep this order.
        executor: default `SequentialExecutor()`.
        num_cpus: CPUs one unit uses (its threads are pinned to it; Ray schedules by it).
        retries: attempts after the first, for a unit that raises or whose worker dies.
        resume_file: JSONL of finished units, appended as each ends.
        resume: skip the units the resume file holds a result for.
        progress: the driver's progress bar.
    """
    ids = [u.id for u in units]
    if len(set(ids)) != len(ids):
        raise InvalidInputError("unit ids must be unique within a sweep")
    if retries < 0 or num_cpus <= 0:
        raise InvalidInputError(f"retries must be >= 0 and num_cpus > 0, got {retries}, {num_cpus}")
    executor = executor or SequentialExecutor()
    t0 = time.perf_counter()
    previous = read_resume_file(resume_file) if (resume and resume_file is not None) else {}
    results: dict[str, Any] = {}
    walls: dict[str, float] = {}
    for uid in ids:
        entry = previous.get(uid)
        if entry is not None and entry.get("ok"):
            results[uid] = entry["result"]
            walls[uid] = float(entry.get("wall_s", 0.0))
    resumed = tuple(uid for uid in ids if uid in results)
    todo = [u for u in units if u.id not in results]
    failures: dict[str, UnitFailure] = {}
    sink = None
    if resume_file is not None:
        Path(resume_file).parent.mkdir(parents=True, exist_ok=True)
        sink = Path(resume_file).open("a" if resume else "w")
    bar = _Progress(progress, label, len(units), len(resumed))

    def on_running(n: int) -> None:
        bar.running = n
        bar.update()

    try:
        for outcome in executor.run(fn, todo, num_cpus, retries, on_running):
            if outcome.ok:
                results[outcome.unit] = outcome.result
                walls[outcome.unit] = outcome.wall_s
                line = {"unit": outcome.unit, "ok": True, "result": outcome.result, "wall_s": outcome.wall_s}
                bar.done += 1
            else:
                assert outcome.failure is not None
                failures[outcome.unit] = outcome.failure
                line = {"unit": outcome.unit, "ok": False, "failure": asdict(outcome.failure)}
                bar.failed += 1
            if sink is not None:
                sink.write(json.dumps(line) + "\n")
                sink.flush()
            bar.update()
    finally:
        bar.close()
        if sink is not None:
            sink.close()
    order = {uid: k for k, uid in enumerate(ids)}
    return SweepResult(
        results=dict(sorted(results.items(), key=lambda kv: order[kv[0]])),
        failures=dict(sorted(failures.items(), key=lambda kv: order[kv[0]])),
        resumed=resumed,
        unit_wall_s=dict(sorted(walls.items(), key=lambda kv: order[kv[0]])),
        wall_s=time.perf_counter() - t0,
        executor=executor.describe(),
        order=tuple(ids),
    )
