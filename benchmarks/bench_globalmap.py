"""Global map vs full merge vs virtual map, on submaps of 200 sonar scans (96 beams) at 0.1 m.

Measures, in one run: full-merge time against the number of submaps, `update_poses` time
against the number of re-applied submaps, and the 100k-ray planner workload on the GlobalMap
and on the VogMap (virtual) against the number of submaps (Sodhi et al., Fig. 8). Writes JSON
and a PNG.

    python benchmarks/bench_globalmap.py --out benchmarks/results [--submaps 300]
"""

from __future__ import annotations

import argparse
import json
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
from vogjax.scenes import analytic  # noqa: E402
from vogjax.report.timing import planner_rays  # noqa: E402

SCANS_PER_SUBMAP = 200


def build_vog(num_submaps: int, device) -> vj.VogMap:
    """Submaps cut from sonar orbits of the pier at several radii and depths, each in the frame
    of its first scan (position and heading)."""
    scene = analytic.pier()
    vog = vj.VogMap(vj.MapConfig(), device=device)
    per_lap = 1500
    for k in tqdm(range(num_submaps), desc="building submaps", unit="submap"):
        lap, part = divmod(k * SCANS_PER_SUBMAP, per_lap)
        sweep = analytic.orbit_sweep(scene, per_lap, radius_m=7.5 + 0.7 * (lap % 4),
                                     depths_m=(2.0 + 0.5 * (lap % 5),), seed=lap)
        rows = slice(part * 96, (part + SCANS_PER_SUBMAP) * 96)
        origins = sweep.origins[part:part + SCANS_PER_SUBMAP].astype(np.float64)
        points = sweep.points[rows].astype(np.float64)
        heading = -origins[0, :2] / np.linalg.norm(origins[0, :2])
        pose = np.eye(4)
        pose[:2, :2] = [[heading[0], -heading[1]], [heading[1], heading[0]]]
        pose[:3, 3] = origins[0]
        to_local = lambda p: (p - pose[:3, 3]) @ pose[:3, :3]  # noqa: E731
        i = vog.add_submap(pose)
        vog.submap(i).integrate_scans(to_local(origins), to_local(points),
                                      sweep.scan_index[rows] - part)
    return vog


def timed(fn, repeats=1):
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        wp.synchronize()
        best = min(best, time.perf_counter() - start)
    return best, result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--submaps", type=int, default=300)
    parser.add_argument("--rays", type=int, default=100_000)
    parser.add_argument("--device", default=None)
    args = parser.parse_args()
    vog = build_vog(args.submaps, args.device)
    device = vog.device
    counts = [n for n in (10, 30, 100, 200, 300, 500, 1000) if n <= args.submaps]
    rng = np.random.default_rng(0)

    # Warm up every kernel once before timing.
    warm = vj.GlobalMap(vog.config, device=device)
    warm.merge(_prefix(vog, 2))
    warm.raycast(np.zeros((4, 3)), np.ones((4, 3)), 1.0)
    _prefix(vog, 2).raycast(np.zeros((4, 3)), np.ones((4, 3)), 1.0)

    merge, queries = [], []
    for n in tqdm(counts, desc="merge and queries", unit="size"):
        sub = _prefix(vog, n)
        gmap = vj.GlobalMap(vog.config, device=device)
        seconds, pulls = timed(lambda: gmap.merge(sub), repeats=2)
        merge.append({"submaps": n, "seconds": seconds, "voxel_updates": pulls,
                      "blocks": gmap._store.live_blocks, "memory_bytes": gmap.memory_bytes()})
        origins, directions = planner_rays(gmap, args.rays, rng)
        t_global, _ = timed(lambda: gmap.raycast(origins, directions, 4.0), repeats=3)
        t_virtual, _ = timed(lambda: sub.raycast(origins, directions, 4.0))
        queries.append({"submaps": n, "global_s": t_global, "virtual_s": t_virtual})

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
        seconds, report = timed(lambda: gmap.update_poses(vog))
        updates.append({"reapplied": len(report.reapplied), "seconds": seconds,
                        "voxel_updates": report.voxels_touched})
        vog.set_poses(ids, home[ids])
        gmap.update_poses(vog)

    result = {"machine": {"device": str(device), "cpu": platform.machine(),
                          "python": platform.python_version(), "warp": wp.__version__},
              "scans_per_submap": SCANS_PER_SUBMAP, "beams_per_scan": 96, "voxel_size_m": 0.1,
              "rays": args.rays, "ray_length_m": 4.0,
              "full_merge": merge, "queries": queries, "update_poses": updates}
    args.out.mkdir(parents=True, exist_ok=True)
    name = f"globalmap_{device.alias.split(':')[0]}"
    (args.out / f"{name}.json").write_text(json.dumps(result, indent=2))
    _plot(result, args.out / f"{name}.png")
    for row in merge:
        print(f"full merge {row['submaps']:4d} submaps: {row['seconds'] * 1e3:8.1f} ms")
    for row in updates:
        print(f"update_poses re-applying {row['reapplied']:4d}: {row['seconds'] * 1e3:8.1f} ms")
    for row in queries:
        print(f"100k rays, {row['submaps']:4d} submaps: global {row['global_s'] * 1e3:7.1f} ms, "
              f"virtual {row['virtual_s'] * 1e3:8.1f} ms")
    print(f"wrote {args.out / name}.json and .png")


def _prefix(vog: vj.VogMap, n: int) -> vj.VogMap:
    """A VogMap sharing the first n submaps of `vog` (no copies)."""
    return vog.view(np.arange(n))


def _plot(result: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), dpi=110)
    merge, queries, updates = result["full_merge"], result["queries"], result["update_poses"]
    axes[0].plot([r["submaps"] for r in merge], [r["seconds"] for r in merge], "o-")
    axes[0].set(xlabel="submaps", ylabel="seconds", title="full merge")
    axes[1].plot([r["reapplied"] for r in updates], [r["seconds"] for r in updates], "o-")
    axes[1].set(xlabel="submaps re-applied", ylabel="seconds", title="update_poses (undo + redo)")
    n = [r["submaps"] for r in queries]
    axes[2].plot(n, [r["global_s"] for r in queries], "o-", label="global map")
    axes[2].plot(n, [r["virtual_s"] for r in queries], "s-", label="virtual map")
    axes[2].set(xlabel="submaps", ylabel="seconds", title=f"{result['rays'] // 1000}k-ray query",
                yscale="log")
    axes[2].legend()
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"{result['scans_per_submap']} sonar scans per submap, {result['machine']['device']}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()
