"""SLAM timings: iSAM2 update plus marginals of the moved submaps per loop closure on graphs of
100 to 1000 submaps, the closure screen and robust loss against the Gaussian graph, ICP of two
5k-point clouds, and the loop-closure front end (correlative searches, then ICP, for a
submap's candidates at once) on the host and on a Warp device side by side. Writes
slam_cpu.json (slam_cuda.json with a CUDA --device).

    python benchmarks/bench_slam.py --out benchmarks/results [--device cuda:0]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import vogjax as vj
from vogjax import devices, slam
from vogjax.geometry import inverse, pose_deltas
from vogjax.slam import loop_closure


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
    return {
        "submaps": num_submaps,
        "loop_closures": closures,
        "median_s": float(np.median(seconds)),
        "max_s": float(seconds.max()),
        "mean_moved": float(np.mean([m for _, m in times])),
    }


def screen_timings(num_submaps: int, closures: int, seed: int = 0) -> dict:
    """What the pose graph's screen and robust loss cost per loop closure: the same lawnmower
    graph and closures with `PoseGraphConfig` as set (screen, Cauchy) against the Gaussian graph
    (screen and loss off), add_loop_closure + update timed for each, side by side."""
    out = {"submaps": num_submaps, "loop_closures": closures}
    for name, config in (
        ("gaussian", slam.PoseGraphConfig(screen="none", robust_loss="none")),
        ("screened_robust", slam.PoseGraphConfig()),
    ):
        rng = np.random.default_rng(seed)
        truth, nav = lawnmower(num_submaps, rng)
        pg = slam.PoseGraph(vj.NavNoise(), prior_pose=truth[0], config=config)
        for T in nav:
            pg.add_submap(T, 40.0)
        pg.update()
        cov = np.diag([1e-4] * 3 + [1e-3] * 3)
        add_s, update_s = [], []
        for _ in range(closures):
            k = int(rng.integers(num_submaps // 2, num_submaps))
            i = int(rng.integers(0, k - 2))
            start = time.perf_counter()
            pg.add_loop_closure(i, k, inverse(truth[i]) @ truth[k], cov)
            add_s.append(time.perf_counter() - start)
            start = time.perf_counter()
            pg.update()
            update_s.append(time.perf_counter() - start)
        out[name] = {"add_median_s": float(np.median(add_s)), "update_median_s": float(np.median(update_s))}
    return out


def icp_timings(rng, points=5000, repeats=5) -> dict:
    walls = [
        np.c_[rng.uniform(0, 8, points // 4), rng.uniform(0, 6, points // 4), np.zeros(points // 4)],
        np.c_[np.zeros(points // 4), rng.uniform(0, 6, points // 4), rng.uniform(0, 3, points // 4)],
        np.c_[rng.uniform(0, 8, points // 4), np.zeros(points // 4), rng.uniform(0, 3, points // 4)],
        np.c_[rng.uniform(3, 5, points // 4), rng.uniform(2, 4, points // 4), np.full(points // 4, 1.5)],
    ]
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
        out[method] = {
            "median_s": float(np.median(seconds)),
            "iterations": result.iterations,
            "converged": result.converged,
        }
    return out


def swath_cloud(rng, points: int) -> np.ndarray:
    """One point per occupied 0.1 m voxel of a seabed with posts, a submap's cloud in kind."""
    x, y = rng.uniform(0, 4, points), rng.uniform(0, 3, points)
    seabed = np.c_[x, y, 0.3 * np.sin(1.7 * x) + 0.2 * np.cos(2.3 * y)]
    posts = np.c_[
        rng.integers(0, 4, points // 3) + rng.normal(0, 0.1, points // 3),
        rng.integers(0, 3, points // 3) + rng.normal(0, 0.1, points // 3),
        rng.uniform(0, 2, points // 3),
    ]
    return np.unique(np.floor(np.concatenate([seabed, posts]) / 0.1), axis=0) * 0.1 + 0.05


def front_end_batches(rng, batches: int, candidates: int, yaw_radius_rad: float) -> list:
    """Per batch, a new submap's candidates: (source, prepared target, T_init, radius_m,
    yaw_radius_rad), the source seen from up to 0.8 m and 0.5 degrees away, navigation a further
    0.5 m off."""
    config = slam.LoopClosureConfig()
    found = []
    for _ in range(batches):
        pairs = []
        for _ in range(candidates):
            target = swath_cloud(rng, 1500)
            truth = np.eye(4)
            truth[:3, :3] = Rotation.from_euler("z", rng.uniform(-0.009, 0.009)).as_matrix()
            truth[:2, 3] = rng.uniform(-0.8, 0.8, 2)
            source = (target - truth[:3, 3]) @ truth[:3, :3]
            source = source[rng.random(len(source)) < 0.7]
            source = source + rng.normal(0, 0.02, source.shape)  # another visit's voxel means
            T_init = truth.copy()
            T_init[:2, 3] += rng.uniform(-0.5, 0.5, 2)
            pairs.append((source, slam.prepare_target(target, config.icp), T_init, 2.0, yaw_radius_rad))
        found.append(pairs)
    return found


def front_end_timings(device: str, batches: int = 8, candidates: int = 5, repeats: int = 3) -> dict:
    """The default aligner on a submap's candidates, host against `device`, alternating, after
    one untimed pass each (kernel builds); and in how many pairs both give the same ICP result
    (the same pose, or no ICP at all)."""
    rng = np.random.default_rng(1)
    out = {"device": device, "batches": batches, "candidates": candidates}
    for name, config in (
        ("translation", slam.LoopClosureConfig()),
        ("six_dof", slam.LoopClosureConfig(icp=slam.IcpConfig(free="all"))),
    ):
        work = front_end_batches(rng, batches, candidates, 0.0 if name == "translation" else 0.02)
        seconds = {None: [], device: []}
        alignments = {}
        for repeat in range(repeats + 1):
            for where in (None, device):
                start = time.perf_counter()
                phases = {}
                alignments[where] = [loop_closure.correlative_then_icp(pairs, config, phases, where) for pairs in work]
                if repeat:
                    seconds[where].append((time.perf_counter() - start, phases))
        same = sum(
            (a.icp is None and b.icp is None)
            or (
                a.icp is not None and b.icp is not None and np.array_equal(a.icp.T_target_source, b.icp.T_target_source)
            )
            for host, dev in zip(alignments[None], alignments[device])
            for a, b in zip(host, dev)
        )
        summary = {}
        for where, label in ((None, "host"), (device, "device")):
            total = [t for t, _ in seconds[where]]
            summary[label] = {
                "median_s_per_batch": float(np.median(total)) / batches,
                **{
                    f"{phase}_s_per_batch": float(np.median([p[phase] for _, p in seconds[where]])) / batches
                    for phase in ("correlative_search", "icp")
                },
            }
        summary["same_icp_results"] = f"{same} of {batches * candidates}"
        summary["host_over_device"] = summary["host"]["median_s_per_batch"] / summary["device"]["median_s_per_batch"]
        out[name] = summary
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--closures", type=int, default=10)
    parser.add_argument("--device", default=None, help="Warp device for the front end (default: CUDA if any, else cpu)")
    args = parser.parse_args()
    device = str(devices.resolve(args.device))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"slam_{'cuda' if device.startswith('cuda') else 'cpu'}.json"
    rng = np.random.default_rng(0)
    graphs = [loop_closure_timings(n, args.closures, rng) for n in (100, 300, 1000)]
    result = {
        "machine": {"cpu": platform.machine(), "python": platform.python_version(), "device": device},
        "loop_closure_update": graphs,
        "screen": [screen_timings(n, args.closures) for n in (100, 300)],
        "icp": icp_timings(rng),
        "front_end": front_end_timings(device),
    }
    path.write_text(json.dumps(result, indent=2))
    for g in graphs:
        print(
            f"{g['submaps']:5d} submaps: update + marginals of {g['mean_moved']:.0f} moved submaps "
            f"per loop closure: median {g['median_s'] * 1e3:.1f} ms, max {g['max_s'] * 1e3:.1f} ms"
        )
    for part in result["screen"]:
        g, r = part["gaussian"], part["screened_robust"]
        print(
            f"{part['submaps']:5d} submaps: add_loop_closure {g['add_median_s'] * 1e3:.2f} ms Gaussian, "
            f"{r['add_median_s'] * 1e3:.2f} ms screened; update {g['update_median_s'] * 1e3:.1f} / "
            f"{r['update_median_s'] * 1e3:.1f} ms (Cauchy)"
        )
    for method in ("point_to_plane", "point_to_point_xyh"):
        print(f"ICP {method}, two 5k-point clouds: {result['icp'][method]['median_s'] * 1e3:.1f} ms")
    front = result["front_end"]
    for name in ("translation", "six_dof"):
        part = front[name]
        print(
            f"front end ({name}), {front['candidates']} candidates per submap: host "
            f"{part['host']['median_s_per_batch'] * 1e3:.1f} ms, {device} "
            f"{part['device']['median_s_per_batch'] * 1e3:.1f} ms "
            f"(search {part['host']['correlative_search_s_per_batch'] * 1e3:.1f} / "
            f"{part['device']['correlative_search_s_per_batch'] * 1e3:.1f} ms, ICP "
            f"{part['host']['icp_s_per_batch'] * 1e3:.1f} / "
            f"{part['device']['icp_s_per_batch'] * 1e3:.1f} ms), host / device {part['host_over_device']:.2f}x, "
            f"same ICP results {part['same_icp_results']}"
        )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
