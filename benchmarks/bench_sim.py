"""Simulation throughput on the CPU: a 10,000-scan propeller survey (vehicle in MJX, sonar in
Warp, drifting navigation, HDF5 written), end to end. Writes JSON.

    python benchmarks/bench_sim.py --out benchmarks/results [--scans 10000]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from vogjax import scenes
from vogjax.config import SonarConfig
from vogjax.sim import simulate_run, vehicle


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--scans", type=int, default=10_000)
    parser.add_argument("--scene", default="propeller")
    args = parser.parse_args()
    scene = scenes.load(args.scene)
    _ = scene.warp_mesh  # build the BVH before timing
    with tempfile.TemporaryDirectory() as folder:
        # warm-up: compiles the MJX step for this many scans and the sonar kernel
        simulate_run(args.scene, Path(folder) / "warm.h5", laps=20, num_scans=args.scans, progress=False)
        start = time.perf_counter()
        summary = simulate_run(
            args.scene,
            Path(folder) / "run.h5",
            laps=20,
            num_scans=args.scans,
            sensor=SonarConfig(range_noise_m=0.02),
            progress=False,
        )
        seconds = time.perf_counter() - start
        size = (Path(folder) / "run.h5").stat().st_size
        # the vehicle alone, many at once
        waypoints = np.tile(scene.start_pose[:3, 3].tolist() + [1.5], (4, 2, 1)) + [[0, 0, 0, 0], [1, 1, 0, 0]]
        vehicle.simulate_batch([scene.start_pose] * 4, waypoints, 2000)
        start = time.perf_counter()
        vehicle.simulate_batch([scene.start_pose] * 4, waypoints, 2000)
        batch_seconds = time.perf_counter() - start
    result = {
        "machine": {"cpu": platform.machine(), "python": platform.python_version()},
        "scene": args.scene,
        "scans": summary.scans,
        "beams_per_scan": 96,
        "survey_s": summary.duration_s,
        "seconds": seconds,
        "scans_per_s": summary.scans / seconds,
        "file_bytes": size,
        "returns": summary.returns,
        "vmap_4_vehicles_2000_scans_s": batch_seconds,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "sim_cpu.json").write_text(json.dumps(result, indent=2))
    print(
        f"{summary.scans} scans ({summary.duration_s / 60:.0f} min of survey) simulated and written in "
        f"{seconds:.1f} s: {summary.scans / seconds:,.0f} scans/s; 4 vehicles x 2000 scans in MJX (vmap): "
        f"{batch_seconds:.2f} s"
    )


if __name__ == "__main__":
    main()
