"""Many runs at once: one Ray task per run, each calling `vogjax.report.map_run`
(`pip install 'vogjax[workers]'`).

    outcomes = map_runs_parallel(["a.h5", "b.h5"], "out", workers=2)            # a local Ray
    outcomes = map_runs_parallel(paths, "out", workers=16, address="ray://head:10001")   # a cluster

At most `workers` runs are mapped at a time, each in its own process, so a run that fails (a
damaged file, an error while mapping, a crashed worker) fails alone: its outcome carries the
error and the other runs finish. A task takes one CPU and, when the cluster has GPUs, a share of
them (GPUs / workers, at most one), so several runs can share one GPU; JAX's memory
preallocation is off in every worker (XLA_PYTHON_CLIENT_PREALLOCATE=false) for that reason.
Ray stays quiet: no dashboard, no banner, worker output not forwarded, errors only.

Run files and the output folder must be reachable at the same paths from every node (a shared
file system), and every node needs the same vogjax installed.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import warnings
from collections.abc import Iterable
from os import PathLike
from pathlib import Path
from types import ModuleType

from vogjax.config import JobConfig
from vogjax.io.atomic import check_writable
from vogjax.report.job import check_job, refuse_existing

WORKER_ENV = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
# forwarded from this process when set, so workers find the same caches and devices
FORWARDED_ENV = ("WARP_CACHE_PATH", "CUDA_VISIBLE_DEVICES", "JAX_PLATFORMS")


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What became of one run of `map_runs_parallel`.

    Attributes
    ----------
    path : Path
        The run file.
    report : dict or None
        Its report, as written to report.json; None when it failed.
    error : str or None
        Why it failed, in one line; None when it succeeded.
    """

    path: Path
    report: dict | None
    error: str | None


def ray_module() -> ModuleType:
    """Import Ray, an optional dependency.

    Returns
    -------
    module
        The `ray` module.

    Raises
    ------
    ValueError
        If Ray is not installed, naming the extra that installs it (``vogjax[workers]``).
    """
    try:
        import ray
    except ImportError:
        raise ValueError("--workers needs Ray: pip install 'vogjax[workers]'") from None
    return ray


def map_runs_parallel(
    paths: Iterable[str | PathLike],
    out: str | PathLike,
    config: JobConfig | None = None,
    workers: int = 2,
    address: str | None = None,
    progress: bool = False,
    overwrite: bool = False,
    sensor_preset: str = "auto",
    given: Iterable[str] | None = None,
) -> list[Outcome]:
    """Map every run with Ray tasks, each run in its own worker process (`map_run`).

    A run that fails fails alone: its outcome carries the error and the other runs finish. The
    settings, the run files and the output folders are checked before Ray starts.

    Parameters
    ----------
    paths : iterable of str or os.PathLike
        Run files (.h5), reachable at these paths from every node; no two with the same name.
    out : str or os.PathLike
        The output folder: run ``NAME.h5`` is written to ``out/NAME/``.
    config : JobConfig or None, optional
        The job's settings (default: ``JobConfig()``).
    workers : int, optional
        Runs mapped at a time (each task takes one CPU and a share of the GPUs, at most one).
    address : str or None, optional
        A Ray cluster's address (such as "ray://head:10001"); None starts a local Ray with
        `workers` CPUs, shut down again when done.
    progress : bool, optional
        Show a progress bar of finished runs (on stderr).
    overwrite : bool, optional
        Replace a run's existing folder; without it an existing one is an error, raised before
        any work.
    sensor_preset : str, optional
        As `vogjax.report.map_runs`'s: each run's preset ("auto": from its metadata).
    given : iterable of str or None, optional
        The settings the caller set, kept over the presets' (None: those differing from the
        defaults).

    Returns
    -------
    list of Outcome
        One per run, in the order of `paths`.

    Raises
    ------
    ValueError
        If `workers` is not a positive integer, `config` is not a JobConfig, `paths` is empty,
        names a missing file or two runs with the same name, an output folder cannot be
        written, Ray is not installed, or Ray cannot be started or reached.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"--workers must be a positive integer, got {workers!r}")
    config, paths = check_job(paths, config)
    for path in paths:
        if not path.is_file():
            raise ValueError(f"path {str(path)!r} does not exist")
    out = Path(out)
    for path in paths:
        refuse_existing(out / path.stem, overwrite)
        check_writable(out / path.stem, folder=True)
    ray = ray_module()
    out.mkdir(parents=True, exist_ok=True)
    started = _start(ray, address, workers)
    try:
        settings = (config, sensor_preset, None if given is None else set(given))
        return _run_all(ray, paths, out, settings, workers, progress)
    finally:
        if started:
            ray.shutdown()


def _start(ray, address: str | None, workers: int) -> bool:
    """Connect to Ray; True when this call started it (and so shuts it down)."""
    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage-stats notice
    env = {**WORKER_ENV, **{k: os.environ[k] for k in FORWARDED_ENV if k in os.environ}}
    options = dict(
        include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR, runtime_env={"env_vars": env}
    )
    try:
        with warnings.catch_warnings():
            # JAX warns of any fork; Ray's fork is followed by exec, so nothing is shared
            warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
            if address is None:
                ray.init(num_cpus=workers, **options)
            else:
                ray.init(address=address, **options)
    except (ConnectionError, RuntimeError, ValueError) as error:
        where = "a local Ray" if address is None else f"the Ray cluster at {address!r}"
        raise ValueError(f"--address: cannot start or reach {where}: {str(error).splitlines()[0]}") from None
    return True


def _run_all(ray, paths, out: Path, settings: tuple, workers: int, progress: bool) -> list[Outcome]:
    from tqdm import tqdm

    gpus = float(ray.cluster_resources().get("GPU", 0.0))
    task = ray.remote(num_cpus=1, num_gpus=min(1.0, gpus / workers) if gpus else 0, max_retries=1)(_map_one)
    outcomes: dict[int, Outcome] = {}
    pending, waiting = {}, list(enumerate(paths))
    with tqdm(total=len(paths), unit="run", desc="mapping runs", disable=not progress) as bar:
        while waiting or pending:
            while waiting and len(pending) < workers:  # at most `workers` in flight
                index, path = waiting.pop(0)
                pending[task.remote(str(path), str(out / path.stem), settings, os.getcwd())] = index
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                index = pending.pop(ref)
                try:
                    outcomes[index] = Outcome(paths[index], ray.get(ref), None)
                except Exception as error:  # the task's error, or Ray's when its worker died
                    outcomes[index] = Outcome(paths[index], None, _one_line(error))
                bar.update(1)
    return [outcomes[i] for i in range(len(paths))]


def _map_one(path: str, out_dir: str, settings: tuple, cwd: str) -> dict:
    """The task: one run mapped in a worker (quiet: no progress bars), from the caller's
    working folder, so relative paths and the report's `run` read as they would one by one
    (an existing folder was refused, or its replacement asked for, before the tasks began)."""
    from vogjax.report.job import map_run

    os.chdir(cwd)
    config, sensor_preset, given = settings
    return map_run(path, out_dir, config, progress=False, overwrite=True, sensor_preset=sensor_preset, given=given)


def _one_line(error: BaseException) -> str:
    """The original error of a failed task as one line (Ray wraps it with a traceback)."""
    cause = getattr(error, "cause", None)
    if isinstance(cause, BaseException):
        error = cause
    text = str(error).strip().splitlines()
    message = text[0] if text else ""
    return f"{type(error).__name__}: {message}" if not isinstance(error, ValueError) else message
