"""SLAM backend timings: iSAM2 update plus marginals of the moved submaps per loop closure on
graphs of 100 to 1000 submaps, and ICP of two 5k-point clouds. Writes JSON.

    python benchmarks/bench_slam.py --out benchmarks/results
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

import vogjax as vj
from vogjax import slam
from vogjax.geometry import inverse, pose_deltas


def lawnmower(num_submaps: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth and drifting navigation poses of submaps on back-and-forth lines."""
    per_line = 20
    truth = []
    for n in range(num_submaps):
        line, along = divmod(n, per_line)
        x = along if line % 2 == 0 else per_line - 1 - along
        T = np.eye(4)
        T[:3, 3] = [x * 1.0, line * 2.0, 0.0]
        truth.append(T)
    truth = np.stack(truth)
    nav = truth.copy()
    drift = np.cumsum(rng.normal(0, 0.05, (num_submaps, 2)), axis=0)
    nav[:, :2, 3] += drift
    return truth, nav


def loop_closure_timings(num_submaps: int, closures: int, rng) -> dict:
    truth, nav = lawnmower(num_submaps, rng)
    pg = slam.PoseGraph(vj.NavNoise(), prior_pose=truth[0])
    for T in nav:
        pg.add_submap(T, 40.0)
    pg.update()
    cov = np.diag([1e-4] * 3 + [1e-3] * 3)
    times = []
    for _ in range(closures):
        k = int(rng.integers(num_submaps // 2, num_submaps))
        i = int(rng.integers(0, k - 2))
        before = pg.poses()
        start = time.perf_counter()
        pg.add_loop_closure(i, k, inverse(truth[i]) @ truth[k], cov)
        after = pg.update()
        angle, shift = pose_deltas(before, after)
        moved = np.flatnonzero((angle > 1e-2) | (shift > 2e-3))
        pg.marginals(moved)
        times.append((time.perf_counter() - start, len(moved)))
    seconds = np.array([t for t, _ in times])
    return {"submaps": num_submaps, "loop_closures": closures, "median_s": float(np.median(seconds)),
            "max_s": float(seconds.max()), "mean_moved": float(np.mean([m for _, m in times]))}


def icp_timings(rng, points=5000, repeats=5) -> dict:
    walls = [np.c_[rng.uniform(0, 8, points // 4), rng.uniform(0, 6, points // 4), np.zeros(points // 4)],
             np.c_[np.zeros(points // 4), rng.uniform(0, 6, points // 4), rng.uniform(0, 3, points // 4)],
             np.c_[rng.uniform(0, 8, points // 4), np.zeros(points // 4), rng.uniform(0, 3, points // 4)],
             np.c_[rng.uniform(3, 5, points // 4), rng.uniform(2, 4, points // 4), np.full(points // 4, 1.5)]]
    target = np.concatenate(walls)
    motion = np.eye(4)
    motion[:3, 3] = [0.2, -0.1, 0.05]
    source = target - motion[:3, 3] + rng.normal(0, 0.01, target.shape)
    out = {"points": points}
    for method in ("point_to_plane", "point_to_point_xyh"):
        seconds, result = [], None
        for _ in range(repeats):
            start = time.perf_counter()
            result = slam.icp(source, target, np.eye(4), method=method)
            seconds.append(time.perf_counter() - start)
        out[method] = {"median_s": float(np.median(seconds)), "iterations": result.iterations,
                       "converged": result.converged}
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--closures", type=int, default=10)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    graphs = [loop_closure_timings(n, args.closures, rng) for n in (100, 300, 1000)]
    result = {"machine": {"cpu": platform.machine(), "python": platform.python_version()},
              "loop_closure_update": graphs, "icp": icp_timings(rng)}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "slam_cpu.json").write_text(json.dumps(result, indent=2))
    for g in graphs:
        print(f"{g['submaps']:5d} submaps: update + marginals of {g['mean_moved']:.0f} moved submaps "
              f"per loop closure: median {g['median_s'] * 1e3:.1f} ms, max {g['max_s'] * 1e3:.1f} ms")
    for method in ("point_to_plane", "point_to_point_xyh"):
        print(f"ICP {method}, two 5k-point clouds: {result['icp'][method]['median_s'] * 1e3:.1f} ms")
    print(f"wrote {args.out / 'slam_cpu.json'}")


if __name__ == "__main__":
    main()
