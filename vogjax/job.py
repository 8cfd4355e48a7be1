"""`vogjax map`: reprocess recorded runs into maps, evaluate them, and write a report per run.

    reports = vj.job.map_runs(["run.h5"], "out", vj.job.load_config("settings.toml"))

Per run, in DIR/<run name>/: global_map.vog, trajectories.csv, report.json and figures
(top_view.png, trajectory.png, roc.png, timing.png). A run's folder appears only once every
file in it is written; inputs and settings are checked before anything is written.
"""

from __future__ import annotations

import dataclasses
from importlib import metadata
import json
import os
import platform
import shutil
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

import vogjax
from vogjax import eval as evaluation
from vogjax import pipeline, plots, scenes, timing
from vogjax.config import replace_from_dict
from vogjax.io.dataset import Dataset

SCAN_RATE_HZ = 5.0  # when a run's metadata does not say


@dataclasses.dataclass(frozen=True)
class ReportConfig:
    """rays: planner rays per timed query; timing_samples: submap counts at which full merges
    and queries are timed (0: no timing curves); surface_points: samples of the true surface
    for the reconstruction RMSE."""

    rays: int = 100_000
    timing_samples: int = 6
    surface_points: int = 50_000

    def __post_init__(self):
        for name in ("rays", "surface_points"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"ReportConfig.{name} must be a positive integer, got {getattr(self, name)!r}")
        if not (isinstance(self.timing_samples, int) and self.timing_samples >= 0):
            raise ValueError(f"ReportConfig.timing_samples must be an integer >= 0, got {self.timing_samples!r}")


@dataclasses.dataclass(frozen=True)
class JobConfig:
    pipeline: pipeline.PipelineConfig = pipeline.PipelineConfig()
    report: ReportConfig = ReportConfig()


# TOML tables and the part of JobConfig each one sets
_TABLES = {"map": ("pipeline", "map"), "nav_noise": ("pipeline", "nav_noise"),
           "loop_closure": ("pipeline", "loop_closure"), "pipeline": ("pipeline",), "report": ("report",)}


def load_config(path) -> JobConfig:
    """JobConfig from a TOML file with tables [map], [nav_noise], [loop_closure] (and
    [loop_closure.icp], [loop_closure.correlative]), [pipeline] and [report]; anything not
    given keeps its default. `scans_per_submap = "covariance"` cuts submaps by Eq. 2."""
    path = Path(path)
    try:
        values = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"config {str(path)!r} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, IsADirectoryError) as error:
        raise ValueError(f"config {str(path)!r} is not valid TOML: {error}") from None
    return config_from_dict(values)


def config_from_dict(values: dict) -> JobConfig:
    config = JobConfig()
    unknown = sorted(set(values) - set(_TABLES))
    if unknown:
        raise ValueError(f"unknown config table(s) {', '.join(unknown)} (known: {', '.join(_TABLES)})")
    by_covariance = isinstance(values.get("pipeline"), dict) and values["pipeline"].get("scans_per_submap") == "covariance"
    if by_covariance:  # TOML has no None: Eq. 2 cutting is spelled out
        values = {**values, "pipeline": {k: v for k, v in values["pipeline"].items() if k != "scans_per_submap"}}
    for table, (part, *field) in _TABLES.items():
        if table not in values:
            continue
        owner = getattr(config, part)
        if field:
            owner = dataclasses.replace(owner, **{field[0]: replace_from_dict(getattr(owner, field[0]),
                                                                               values[table], table)})
        else:
            owner = replace_from_dict(owner, values[table], table)
        config = dataclasses.replace(config, **{part: owner})
    if by_covariance:
        config = dataclasses.replace(config, pipeline=dataclasses.replace(config.pipeline, scans_per_submap=None))
    return config


def map_runs(paths, out, config: JobConfig | None = None, progress: bool = True) -> list[dict]:
    """Map each run in `paths` into out/<run name>/; returns the reports."""
    config = config or JobConfig()
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("paths must name at least one run file")
    names = [p.stem for p in paths]
    if len(set(names)) != len(names):
        raise ValueError(f"paths: two runs would share an output folder: {names}")
    for path in paths:  # every input readable before any output is written
        Dataset(path).close()
    out = Path(out)
    return [map_run(path, out / path.stem, config, progress) for path in paths]


def map_run(path, out_dir, config: JobConfig | None = None, progress: bool = True) -> dict:
    """Map one run into `out_dir` (replaced only when everything is written); its report."""
    config = config or JobConfig()
    out_dir = Path(out_dir)
    with Dataset(path) as ds:
        metadata = ds.metadata
        start = time.perf_counter()
        result = pipeline.run(ds, config.pipeline, progress)
        pipeline_s = time.perf_counter() - start
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".partial", dir=out_dir.parent))
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)  # mkdtemp's folder is private; the published one should not be
    try:
        report = _evaluate_and_write(result, Path(path), metadata, pipeline_s, config, staging, progress)
        _publish(staging, out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return report


def _evaluate_and_write(result, path: Path, metadata: dict, pipeline_s: float, config: JobConfig,
                        folder: Path, progress: bool) -> dict:
    scene = scenes.load(metadata["scene"]) if metadata.get("scene") in scenes.NAMES else None
    metrics, roc = evaluation.evaluate_run(result, scene, config.report.surface_points) if scene else ({}, {})
    curves = (timing.measure(result, config.report.rays, config.report.timing_samples, progress=progress)
              if config.report.timing_samples else None)
    rate_hz = float(metadata.get("sonar", {}).get("rate_hz", SCAN_RATE_HZ))
    report = _report(result, path, metadata, metrics, curves, pipeline_s, rate_hz, config)
    # 1. the map and the trajectories
    result.global_map.save(folder / "global_map.vog")
    pipeline.save_trajectories(result, folder / "trajectories.csv")
    # 2. figures
    centres, log_odds = result.global_map.voxels()
    label = f"{path.stem}: {result.vog.num_submaps} submaps, {len(result.loop_closures)} loop closures"
    plots.top_view(centres, log_odds, result.config.map, folder / "top_view.png", title=f"{label}, top view")
    plots.trajectories(result, folder / "trajectory.png", title=label)
    if roc:
        plots.roc_curves(roc, folder / "roc.png", title=f"{path.stem}: occupancy vs ground truth")
    if curves is not None:
        plots.timing(curves, folder / "timing.png", title=f"{path.stem}, {result.global_map.device}")
    # 3. the report last: its presence says the rest is there
    (folder / "report.json").write_text(json.dumps(report, indent=2, default=_json_default))
    return report


def _report(result, path, metadata, metrics, curves, pipeline_s, rate_hz, config) -> dict:
    steps = {name: float(np.sum(values)) for name, values in result.timings.items() if name != "reapplied"}
    duration_s = result.scans / rate_hz
    timing_s = {"pipeline": pipeline_s, "scans_per_s": result.scans / pipeline_s,
                "real_time_factor": duration_s / pipeline_s, "steps": steps}
    if curves is not None:
        n = len(curves.online_s)
        timing_s["update_per_submap"] = {"online": float(curves.online_s[-1]), "virtual": float(curves.virtual_s[-1]),
                                         "full_merge": float(curves.full_merge_s[-1]), "submaps": n}
        timing_s["query"] = {"rays": curves.rays, "global": float(curves.query_global_s[-1]),
                             "virtual": float(curves.query_virtual_s[-1]),
                             "submaps": int(curves.sampled_submaps[-1])}
        timing_s["curves"] = curves.to_dict()
    empty = dict.fromkeys(("online", "virtual", "full_merge", "standard"))
    return {
        "run": str(path), "scene": metadata.get("scene"), "scans": result.scans, "duration_s": duration_s,
        "submaps": result.vog.num_submaps,
        "auc": metrics.get("auc", empty),
        "rmse_m": metrics.get("rmse_m", dict.fromkeys(("standard", "without_loop_closures", "with_loop_closures"))),
        "agreement": metrics.get("agreement"),
        **result.metrics,
        "timing_s": timing_s,
        "config": dataclasses.asdict(config),
        "versions": _versions(),
        "device": str(result.global_map.device),
    }


def _versions() -> dict:
    """Installed versions, read from package metadata (importing JAX just to ask costs a second)."""
    installed = {name: metadata.version(package) for name, package in
                 (("numpy", "numpy"), ("warp", "warp-lang"), ("jax", "jax"), ("gtsam", "gtsam"))}
    return {"vogjax": vogjax.__version__, "python": platform.python_version(), **installed,
            "platform": platform.platform()}


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _publish(staging: Path, out_dir: Path) -> None:
    """Put the finished folder in place of any earlier one."""
    if out_dir.exists():
        old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
        os.replace(out_dir, old)
        os.replace(staging, out_dir)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(staging, out_dir)


def summary_table(reports: list[dict]) -> str:
    """A short text table of the reports' headline figures."""
    def fmt(value, spec):
        return "-" if value is None else format(value, spec)

    rows = [("run", "submaps", "LC acc/rej", "AUC online", "AUC virtual", "AUC merge", "AUC standard",
             "RMSE std", "RMSE no-LC", "RMSE LC", "traj nav", "traj opt", "update ms", "merge ms",
             "query ms", "x real time")]
    for r in reports:
        t = r["timing_s"]
        upd, query = t.get("update_per_submap", {}), t.get("query", {})
        rows.append((Path(r["run"]).stem, str(r["submaps"]),
                     f"{r['loop_closures']['accepted']}/{r['loop_closures']['rejected']}",
                     *(fmt(r["auc"][k], ".3f") for k in ("online", "virtual", "full_merge", "standard")),
                     *(fmt(r["rmse_m"][k], ".3f") for k in ("standard", "without_loop_closures", "with_loop_closures")),
                     *(fmt(r["trajectory_rmse_m"].get(k), ".2f") for k in ("navigation", "optimized")),
                     fmt(upd.get("online") and upd["online"] * 1e3, ".1f"),
                     fmt(upd.get("full_merge") and upd["full_merge"] * 1e3, ".1f"),
                     fmt(query.get("global") and query["global"] * 1e3, ".1f"),
                     fmt(t["real_time_factor"], ".0f")))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(cell.rjust(w) for cell, w in zip(row, widths)) for row in rows)
