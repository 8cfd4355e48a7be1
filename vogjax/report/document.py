"""report.json: what a run produced and how well, in one document."""

from __future__ import annotations

import dataclasses
import platform
from importlib import metadata as package_metadata

import numpy as np

import vogjax


def build(result, run_path, metrics: dict, curves, pipeline_s: float, config) -> dict:
    """The report of a pipeline `result` of the run at `run_path`, with its ground-truth
    `metrics` ({} when the run has no scene), timing `curves` (or None), the pipeline's wall
    time and the JobConfig used."""
    steps = {
        name: float(np.sum(values)) for name, values in result.timings.items() if name not in ("reapplied", "closures")
    }
    duration_s = result.duration_s
    mapping_s = pipeline_s - steps.get("probes", 0.0)  # the probes' time is not the pipeline's
    timing_s = {
        "pipeline": mapping_s,
        "scans_per_s": result.scans / mapping_s,
        "real_time_factor": duration_s / mapping_s,
        "steps": steps,
        "slam_on_second_thread": result.slam_on_second_thread,
    }
    if curves is not None:
        n = len(curves.online_s)
        timing_s["update_per_submap"] = {
            "online": float(curves.online_s[-1]),
            "virtual": float(curves.virtual_s[-1]),
            "full_merge": float(curves.full_merge_s[-1]),
            "submaps": n,
        }
        timing_s["query"] = {
            "rays": curves.rays,
            "global": float(curves.query_global_s[-1]),
            "virtual": float(curves.query_virtual_s[-1]),
            "submaps": int(curves.sampled_submaps[-1]),
        }
        timing_s["curves"] = curves.to_dict()
        timing_s["reapplied_per_submap"] = float(np.mean(curves.reapplied))
    empty = dict.fromkeys(("online", "virtual", "full_merge", "standard"))
    return {
        "run": str(run_path),
        "scene": result.metadata.get("scene"),
        "ground_truth": (
            "scene" if metrics else "none: the run names no built-in scene, so AUC, RMSE and agreement are skipped"
        ),
        "scans": result.scans,
        "duration_s": duration_s,
        "submaps": result.vog.num_submaps,
        "auc": metrics.get("auc", empty),
        "auc_aligned": metrics.get("auc_aligned", {}),
        "auc_vs_reference": metrics.get("auc_vs_reference", {}),
        "confidence_map": metrics.get("confidence_map", {}),
        "rmse_m": metrics.get("rmse_m", dict.fromkeys(("standard", "without_loop_closures", "with_loop_closures"))),
        "agreement": metrics.get("agreement"),
        **result.metrics,
        "returns": _returns(result),
        "scan_matching": {
            "enabled": False,
            "registered": 0,
            "failed": 0,
            **result.scan_matching,
        },
        "timing_s": timing_s,
        "fig9": curves.fig9() if curves is not None else None,
        "config": dataclasses.asdict(config),
        "versions": versions(),
        "device": str(result.global_map.device),
    }


def _returns(result) -> dict:
    """The returns read, those past the map's reach (they cleared free space up to it and marked
    nothing), and their share."""
    counts = dict(getattr(result, "returns", {}) or {})
    total, beyond = counts.get("total", 0), counts.get("beyond_reach", 0)
    return {**counts, "beyond_reach_share": beyond / total if total else 0.0}


def versions() -> dict:
    """Installed versions, read from package metadata (importing JAX just to ask costs a second)."""
    installed = {
        name: package_metadata.version(package)
        for name, package in (("numpy", "numpy"), ("warp", "warp-lang"), ("jax", "jax"), ("gtsam", "gtsam"))
    }
    return {
        "vogjax": vogjax.__version__,
        "python": platform.python_version(),
        **installed,
        "platform": platform.platform(),
    }


def finite_or_null(value):
    """`value` (nested dicts, lists, numbers) with every NaN or infinite number as None: JSON
    has no NaN (Python writes a bare NaN that strict readers, jq among them, refuse), and null
    says "not defined here" (an AUC without positives, an error without closures)."""
    if isinstance(value, dict):
        return {key: finite_or_null(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(item) for item in value]
    if isinstance(value, np.ndarray):
        return finite_or_null(value.tolist())
    if isinstance(value, (float, np.floating)) and not np.isfinite(value):
        return None
    return value


def json_default(value):
    """For json.dumps: NumPy scalars and arrays as plain numbers and lists."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
