"""Import throughput of a spinning lidar's bag, with and without deskewing, side by side.

The bag is the importing-a-bag tutorial's (docs/tutorials/make_lidar_bag.py): a 16-ring lidar
on a vehicle circling a room, Velodyne's point layout with per-point times, ROS 2 MCAP. Each
setting is imported `--repeats` times, alternating, and the median is kept. Writes JSON.

    python benchmarks/bench_import.py --out benchmarks/results [--scans 300] [--columns 900]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import runpy
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from vogjax.io.rosbag import import_bag

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--scans", type=int, default=300)
    parser.add_argument("--columns", type=int, default=900, help="columns per sweep (x 16 rings)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        here = os.getcwd()
        os.chdir(folder)  # the tutorial script writes its own small bag where it runs
        try:
            tutorial = runpy.run_path(str(ROOT / "docs" / "tutorials" / "make_lidar_bag.py"), run_name="bench")
        finally:
            os.chdir(here)
        bag = Path(folder) / "bench_bag"
        start = time.perf_counter()
        tutorial["write_lidar_bag"](bag, scans=args.scans, columns=args.columns)
        write_s = time.perf_counter() - start
        bag_bytes = sum(f.stat().st_size for f in bag.rglob("*") if f.is_file())
        import_bag(bag, Path(folder) / "warm.h5", "/velodyne_points", "/odom", frame="velodyne", progress=False)
        seconds = {True: [], False: []}
        cpu = {True: [], False: []}
        run_bytes = {}  # the process's CPU time: less moved by other work on a shared machine
        for _ in range(args.repeats):
            for deskew in (True, False):
                out = Path(folder) / f"run_{deskew}.h5"
                start, start_cpu = time.perf_counter(), time.process_time()
                summary = import_bag(
                    bag, out, "/velodyne_points", "/odom", frame="velodyne", progress=False, deskew=deskew
                )
                seconds[deskew].append(time.perf_counter() - start)
                cpu[deskew].append(time.process_time() - start_cpu)
                run_bytes[deskew] = out.stat().st_size
                out.unlink()
    points = summary.scans * summary.beams
    result = {
        "machine": {"cpu": platform.machine(), "cores": os.cpu_count(), "python": platform.python_version()},
        "commit": _commit(),
        "date": time.strftime("%Y-%m-%d"),
        "scans": summary.scans,
        "points_per_scan": summary.beams,
        "bag_bytes": bag_bytes,
        "run_bytes": {"deskewed": run_bytes[True], "not_deskewed": run_bytes[False]},
        "bag_write_s": write_s,
        "seconds": {"deskewed": statistics.median(seconds[True]), "not_deskewed": statistics.median(seconds[False])},
        "all_seconds": {"deskewed": seconds[True], "not_deskewed": seconds[False]},
        "cpu_seconds": {"deskewed": statistics.median(cpu[True]), "not_deskewed": statistics.median(cpu[False])},
    }
    for key in ("deskewed", "not_deskewed"):
        result[f"scans_per_s_{key}"] = summary.scans / result["seconds"][key]
        result[f"points_per_s_{key}"] = points / result["seconds"][key]
    result["deskew_cost"] = result["seconds"]["deskewed"] / result["seconds"]["not_deskewed"]
    result["deskew_cost_cpu"] = result["cpu_seconds"]["deskewed"] / result["cpu_seconds"]["not_deskewed"]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "import_cpu.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


def _commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
        ).stdout.strip()
    except OSError:
        return ""


if __name__ == "__main__":
    main()
