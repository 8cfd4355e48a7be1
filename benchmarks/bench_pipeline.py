"""The batch pipeline on a simulated propeller survey of 150 submaps: scans per second against
the sonar's real-time rate, and where the time goes. Writes JSON.

    python benchmarks/bench_pipeline.py --out benchmarks/results [--submaps 150]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from vogjax import pipeline
from vogjax.config import SonarConfig
from vogjax.sim import simulate_run
from vogjax.report.timing import planner_rays

STEPS = {  # report name -> pipeline timing names (seconds summed over the run)
    "integration": ["integration"],
    "standard_map": ["standard_map"],
    "loop_closure_search": ["correlative_search"],
    "icp": ["icp"],
    "isam2_and_marginals": ["isam2"],
    "undo_redo": ["undo_redo"],
    "add_submap": ["add"],
    "virtual_pose_update": ["virtual_update"],
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--submaps", type=int, default=150)
    parser.add_argument("--scans-per-submap", type=int, default=100)
    parser.add_argument("--rays", type=int, default=100_000)
    args = parser.parse_args()
    scans = args.submaps * args.scans_per_submap
    config = pipeline.PipelineConfig(scans_per_submap=args.scans_per_submap)
    with tempfile.TemporaryDirectory() as folder:
        run_path = Path(folder) / "propeller.h5"
        # the lawn-mower survey flown until it has enough scans (about 2000 per lap)
        summary = simulate_run("propeller", run_path, laps=scans // 1500 + 1, num_scans=scans,
                               sensor=SonarConfig(range_noise_m=0.02), progress=False)
        # warm-up on a short prefix: kernels compiled and loaded before timing
        pipeline.run(_prefix(run_path, Path(folder) / "warm.h5", 3 * args.scans_per_submap), config, progress=False)
        start = time.perf_counter()
        result = pipeline.run(run_path, config)
        seconds = time.perf_counter() - start
    origins, directions = planner_rays(result.global_map, args.rays)
    result.global_map.raycast(origins[:16], directions[:16], 4.0)
    start = time.perf_counter()
    result.global_map.raycast(origins, directions, 4.0)
    query_s = time.perf_counter() - start
    steps = {name: float(sum(np.sum(result.timings.get(t, 0.0)) for t in names)) for name, names in STEPS.items()}
    survey_s = summary.scans / SonarConfig().rate_hz
    ate = result.metrics["trajectory_rmse_m"]
    device = str(result.global_map.device)
    report = {"machine": {"device": device, "cpu": platform.machine(), "python": platform.python_version()},
              "scene": "propeller", "scans": summary.scans, "submaps": result.vog.num_submaps,
              "survey_s": survey_s, "seconds": seconds, "scans_per_s": summary.scans / seconds,
              "real_time_factor": survey_s / seconds, "steps_s": steps,
              "steps_fraction": {k: v / seconds for k, v in steps.items()},
              "reapplied_submaps": int(np.sum(result.timings["reapplied"])),
              "loop_closures": {"accepted": len(result.loop_closures), "rejected": len(result.rejected)},
              "trajectory_rmse_m": ate, "query_rays": args.rays, "query_s": query_s}
    args.out.mkdir(parents=True, exist_ok=True)
    name = f"pipeline_{device.split(':')[0]}.json"
    (args.out / name).write_text(json.dumps(report, indent=2))
    print(f"{summary.scans} scans, {result.vog.num_submaps} submaps on {device}: {seconds:.1f} s, "
          f"{summary.scans / seconds:,.0f} scans/s = {survey_s / seconds:.0f}x real time (5 Hz sonar)")
    for key, value in sorted(steps.items(), key=lambda kv: -kv[1]):
        print(f"  {key:22s} {value:7.2f} s  {value / seconds:5.1%}")
    print(f"  {args.rays:,} planner rays on the final global map: {query_s * 1e3:.1f} ms")
    print(f"  loop closures {len(result.loop_closures)} accepted, {len(result.rejected)} rejected; "
          f"trajectory RMSE navigation {ate['navigation']:.2f} m, optimised {ate['optimized']:.2f} m")
    print(f"wrote {args.out / name}")


def _prefix(path: Path, out: Path, scans: int) -> Path:
    """A copy of the first `scans` scans of a run."""
    from vogjax.io.dataset import Dataset, DatasetWriter

    with Dataset(path) as ds:
        batch = ds.read(0, scans)
        with DatasetWriter(out, batch.ranges.shape[1], ds.metadata) as writer:
            writer.append(**{name: getattr(batch, name) for name in ("time_s", "pose_truth", "pose_nav", "sonar_origin",
                                                                      "sonar_directions", "ranges", "no_return")})
    return out


if __name__ == "__main__":
    main()
