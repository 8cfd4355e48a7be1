"""Global map vs full merge vs virtual map, on submaps of 200 sonar scans (96 beams) at 0.1 m.

Measures, in one run: full-merge time against the number of submaps on two worlds (the analytic
pier, and a denser one: the pilings scene's mesh swept by a sonar yawing +-18 degrees, about 4x
the pier's voxel updates per submap), `update_poses` time against the number of re-applied
submaps, and the 100k-ray planner workload on the GlobalMap and on the VogMap (virtual) against
the number of submaps (Sodhi et al., Fig. 8). Every timing is repeated (`--repeats`); JSON keeps
the median as "seconds" and every run in "runs_s". Writes JSON and a PNG.

    python benchmarks/bench_globalmap.py --out benchmarks/results [--submaps 300] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import warp as wp  # noqa: E402
from tqdm import tqdm  # noqa: E402

import vogjax as vj  # noqa: E402
from vogjax.report.timing import planner_rays  # noqa: E402
from vogjax.scenes import analytic  # noqa: E402

SCANS_PER_SUBMAP = 200
DENSE_WORLD = (
    "pilings scene (mesh: seabed, deck, ten slanted piles), sonar (96 beams, 29 deg fan, "
    "11 m) on a vehicle weaving between the pile rows 1.5-4.5 m above the seabed, yawing +-18 deg over "
    "each submap's 200 scans"
)


def build_vog(num_submaps: int, device) -> vj.VogMap:
    """Submaps cut from sonar orbits of the pier at several radii and depths, each in the frame
    of its first scan (position and heading)."""
    scene = analytic.pier()
    vog = vj.VogMap(vj.MapConfig(), device=device)
    per_lap = 1500
    for k in tqdm(range(num_submaps), desc="building pier submaps", unit="submap"):
        lap, part = divmod(k * SCANS_PER_SUBMAP, per_lap)
        sweep = analytic.orbit_sweep(
            scene, per_lap, radius_m=7.5 + 0.7 * (lap % 4), depths_m=(2.0 + 0.5 * (lap % 5),), seed=lap
        )
        rows = slice(part * 96, (part + SCANS_PER_SUBMAP) * 96)
        origins = sweep.origins[part : part + SCANS_PER_SUBMAP].astype(np.float64)
        points = sweep.points[rows].astype(np.float64)
        heading = -origins[0, :2] / np.linalg.norm(origins[0, :2])
        pose = np.eye(4)
        pose[:2, :2] = [[heading[0], -heading[1]], [heading[1], heading[0]]]
        pose[:3, 3] = origins[0]
        _add_submap(vog, pose, origins, points, sweep.scan_index[rows] - part)
    return vog


def build_dense_vog(num_submaps: int, device, yaw_sweep_rad: float = 0.1 * np.pi) -> vj.VogMap:
    """The denser world (DENSE_WORLD): sonar scans simulated against the pilings mesh."""
    from vogjax import scenes
    from vogjax.config import SonarConfig
    from vogjax.sim.ranging import scan

    mesh = scenes.load("pilings").warp_mesh
    sonar = SonarConfig()
    vog = vj.VogMap(vj.MapConfig(), device=device)
    s = np.arange(SCANS_PER_SUBMAP)
    for k in tqdm(range(num_submaps), desc="building dense submaps", unit="submap"):
        phase = (k * SCANS_PER_SUBMAP + s) / (SCANS_PER_SUBMAP * 25.0)
        yaw = 0.37 * k + yaw_sweep_rad * np.sin(2 * np.pi * s / SCANS_PER_SUBMAP)
        poses = np.tile(np.eye(4), (SCANS_PER_SUBMAP, 1, 1))
        poses[:, 0, 0], poses[:, 0, 1] = np.cos(yaw), -np.sin(yaw)
        poses[:, 1, 0], poses[:, 1, 1] = np.sin(yaw), np.cos(yaw)
        poses[:, :3, 3] = np.stack(
            [
                7.0 * np.sin(2 * np.pi * phase),
                1.5 * np.sin(2 * np.pi * 3.1 * phase),
                3.0 + 1.5 * np.sin(2 * np.pi * 1.7 * phase),
            ],
            axis=1,
        )
        sim = scan(mesh, poses, sonar)
        ranges = np.where(sim.no_return, sonar.max_range_m * 1.05 + 0.1, sim.ranges)
        points = (sim.origins[:, None] + sim.directions * ranges[..., None]).reshape(-1, 3)
        valid = ~sim.invalid.reshape(-1)  # a surface within the blind distance: the beam clears nothing
        _add_submap(vog, poses[0], sim.origins, points[valid], np.repeat(s, sonar.beams)[valid])
    return vog


def _add_submap(vog: vj.VogMap, pose: np.ndarray, origins: np.ndarray, points: np.ndarray, scan_index) -> None:
    to_local = lambda p: (p - pose[:3, 3]) @ pose[:3, :3]  # noqa: E731
    i = vog.add_submap(pose)
    vog.submap(i).integrate_scans(to_local(origins), to_local(points), scan_index)


def timed(fn, repeats=1):
    """(median seconds, every run's seconds, the last result)."""
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        wp.synchronize()
        runs.append(time.perf_counter() - start)
    return float(np.median(runs)), runs, result


def merge_curve(vog: vj.VogMap, counts: list, repeats: int, desc: str) -> list:
    rows = []
    for n in tqdm(counts, desc=desc, unit="size"):
        sub = _prefix(vog, n)
        holder = {}

        def merge():
            holder["map"] = vj.GlobalMap(vog.config, device=vog.device)
            return holder["map"].merge(sub)

        seconds, runs, pulls = timed(merge, repeats)
        gmap = holder["map"]
        rows.append(
            {
                "submaps": n,
                "seconds": seconds,
                "runs_s": runs,
                "voxel_updates": pulls,
                "blocks": gmap.store.live_blocks,
                "memory_bytes": gmap.memory_bytes(),
            }
        )
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--submaps", type=int, default=300)
    parser.add_argument("--rays", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--device", default=None)
    args = parser.parse_args()
    vog = build_vog(args.submaps, args.device)
    dense = build_dense_vog(args.submaps, args.device)
    device = vog.device
    counts = [n for n in (10, 30, 100, 200, 300, 500, 1000) if n <= args.submaps]
    rng = np.random.default_rng(0)

    # Warm up every kernel once before timing.
    warm = vj.GlobalMap(vog.config, device=device)
    warm.merge(_prefix(vog, 2))
    warm.raycast(np.zeros((4, 3)), np.ones((4, 3)), 1.0)
    _prefix(vog, 2).raycast(np.zeros((4, 3)), np.ones((4, 3)), 1.0)

    merge = merge_curve(vog, counts, args.repeats, "pier merges")
    dense_merge = merge_curve(dense, counts, args.repeats, "dense merges")
    queries = []
    for n in tqdm(counts, desc="queries", unit="size"):
        sub = _prefix(vog, n)
        gmap = vj.GlobalMap(vog.config, device=device)
        gmap.merge(sub)
        origins, directions = planner_rays(gmap, args.rays, rng)
        t_global, global_runs, _ = timed(lambda: gmap.raycast(origins, directions, 4.0), repeats=args.repeats)
        t_virtual, _, _ = timed(lambda: sub.raycast(origins, directions, 4.0))
        queries.append({"submaps": n, "global_s": t_global, "global_runs_s": global_runs, "virtual_s": t_virtual})

    # update_poses against the number of submaps re-applied, on the largest map
    gmap = vj.GlobalMap(vog.config, device=device)
    gmap.merge(vog)
    home = vog.poses()
    updates = []
    for k in [k for k in (1, 3, 10, 30, 100, 300) if k <= args.submaps]:
        ids = rng.choice(args.submaps, k, replace=False)
        moved = home[ids].copy()
        moved[:, :3, 3] += rng.normal(0, 0.05, (k, 3))
        vog.set_poses(ids, moved)
        seconds, _, report = timed(lambda: gmap.update_poses(vog))
        updates.append({"reapplied": len(report.reapplied), "seconds": seconds, "voxel_updates": report.voxels_touched})
        vog.set_poses(ids, home[ids])
        gmap.update_poses(vog)

    result = {
        "machine": {
            "device": str(device),
            "cpu": platform.machine(),
            "cores": os.cpu_count(),
            "python": platform.python_version(),
            "warp": wp.__version__,
            "load_average": list(os.getloadavg()),
        },  # a shared machine: how busy it was
        "scans_per_submap": SCANS_PER_SUBMAP,
        "beams_per_scan": 96,
        "voxel_size_m": 0.1,
        "rays": args.rays,
        "ray_length_m": 4.0,
        "repeats": args.repeats,
        "full_merge": merge,
        "queries": queries,
        "update_poses": updates,
        "dense_world": {"scene": DENSE_WORLD, "full_merge": dense_merge},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    name = f"globalmap_{device.alias.split(':')[0]}"
    (args.out / f"{name}.json").write_text(json.dumps(result, indent=2))
    _plot(result, args.out / f"{name}.png")
    for world, rows in (("pier", merge), ("dense", dense_merge)):
        for row in rows:
            print(
                f"full merge {world:5s} {row['submaps']:4d} submaps: {row['seconds'] * 1e3:8.1f} ms "
                f"(runs {min(row['runs_s']) * 1e3:.0f}-{max(row['runs_s']) * 1e3:.0f} ms, "
                f"{row['voxel_updates'] / 1e6:.1f} M voxel updates)"
            )
    for row in updates:
        print(f"update_poses re-applying {row['reapplied']:4d}: {row['seconds'] * 1e3:8.1f} ms")
    for row in queries:
        print(
            f"100k rays, {row['submaps']:4d} submaps: global {row['global_s'] * 1e3:7.1f} ms, "
            f"virtual {row['virtual_s'] * 1e3:8.1f} ms"
        )
    print(f"wrote {args.out / name}.json and .png")


def _prefix(vog: vj.VogMap, n: int) -> vj.VogMap:
    """A VogMap sharing the first n submaps of `vog` (no copies)."""
    return vog.view(np.arange(n))


def _plot(result: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), dpi=110)
    merge, queries, updates = result["full_merge"], result["queries"], result["update_poses"]
    dense = result["dense_world"]["full_merge"]
    axes[0].plot([r["submaps"] for r in merge], [r["seconds"] for r in merge], "o-", label="pier")
    axes[0].plot([r["submaps"] for r in dense], [r["seconds"] for r in dense], "s-", label="dense world")
    axes[0].set(xlabel="submaps", ylabel="seconds (median)", title="full merge")
    axes[0].legend()
    axes[1].plot([r["reapplied"] for r in updates], [r["seconds"] for r in updates], "o-")
    axes[1].set(xlabel="submaps re-applied", ylabel="seconds", title="update_poses (undo + redo)")
    n = [r["submaps"] for r in queries]
    axes[2].plot(n, [r["global_s"] for r in queries], "o-", label="global map")
    axes[2].plot(n, [r["virtual_s"] for r in queries], "s-", label="virtual map")
    axes[2].set(xlabel="submaps", ylabel="seconds", title=f"{result['rays'] // 1000}k-ray query", yscale="log")
    axes[2].legend()
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"{result['scans_per_submap']} sonar scans per submap, {result['machine']['device']}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()
