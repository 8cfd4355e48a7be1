"""VoxelMap vs OctoMap, side by side in one run: integration rays/s, the 100k-ray planner
workload, and memory for the same map. Writes JSON (and prints a table).

    python benchmarks/bench_voxelmap.py --out benchmarks/results [--scans 2000]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import octomap
import warp as wp

import vogjax as vj
from vogjax.scenes import analytic
from vogjax.report.timing import planner_rays


def best_of(repeats, fn):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        wp.synchronize()
        times.append(time.perf_counter() - start)
    return min(times)


def octomap_tree(cfg):
    tree = octomap.OcTree(cfg.voxel_size)
    tree.setProbHit(cfg.prob_hit)
    tree.setProbMiss(cfg.prob_miss)
    tree.setOccupancyThres(cfg.occupied_threshold)
    tree.setClampingThresMin(cfg.clamp_min)
    tree.setClampingThresMax(cfg.clamp_max)
    return tree


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--scans", type=int, default=2000)
    parser.add_argument("--rays", type=int, default=100_000)
    parser.add_argument("--device", default=None)
    args = parser.parse_args()
    cfg = vj.MapConfig()
    sweep = analytic.orbit_sweep(analytic.pier(), args.scans)
    num_rays = sweep.points.shape[0]
    per_scan = np.split(sweep.points, args.scans)

    # Integration: a fresh map per repeat; the first run also compiles kernels, so warm up.
    warm = vj.VoxelMap(cfg, device=args.device)
    warm.integrate_scans(sweep.origins[:70], sweep.points[: 70 * 96], sweep.scan_index[: 70 * 96])
    warm.raycast(np.zeros((10, 3)), np.ones((10, 3)), 1.0)
    holder = {}

    def vog_integrate():
        holder["map"] = vj.VoxelMap(cfg, device=args.device)
        holder["map"].integrate_scans(sweep.origins, sweep.points, sweep.scan_index)

    t_vog = best_of(3, vog_integrate)
    vmap = holder["map"]

    def octo_integrate():
        holder["tree"] = octomap_tree(cfg)
        for origin, points in zip(sweep.origins.astype(np.float64), per_scan):
            holder["tree"].insertPointCloud(points.astype(np.float64), origin, maxrange=cfg.max_range)

    t_octo = best_of(1, octo_integrate)
    tree = holder["tree"]

    # Planner workload: rays of at most 4 m from observed free space.
    origins, directions = planner_rays(vmap, args.rays, np.random.default_rng(0))
    length = 4.0
    t_vog_rays = best_of(5, lambda: vmap.raycast(origins, directions, length))
    end = np.zeros(3)

    def octo_rays():
        for o, d in zip(origins, directions):
            tree.castRay(o, d, end, ignoreUnknownCells=True, maxRange=length)

    t_octo_rays = best_of(1, octo_rays)

    result = {
        "machine": {"device": str(vmap.device), "cpu": platform.processor() or platform.machine(),
                    "python": platform.python_version(), "warp": wp.__version__},
        "scene": "analytic pier, orbit sweep", "scans": args.scans, "beams_per_scan": 96,
        "integration": {
            "rays": num_rays,
            "vogjax_s": t_vog, "octomap_s": t_octo,
            "vogjax_rays_per_s": num_rays / t_vog, "octomap_rays_per_s": num_rays / t_octo,
            "speedup": t_octo / t_vog,
        },
        "raycast": {
            "rays": args.rays, "max_range_m": length,
            "vogjax_s": t_vog_rays, "octomap_s": t_octo_rays, "speedup": t_octo_rays / t_vog_rays,
        },
        "memory": {
            "vogjax_bytes": vmap.memory_bytes(), "octomap_bytes": int(tree.memoryUsage()),
            "ratio": vmap.memory_bytes() / tree.memoryUsage(),
            "observed_voxels": int(vmap.voxels()[0].shape[0]), "blocks": vmap.num_blocks,
        },
    }
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"voxelmap_{vmap.device.alias.split(':')[0]}.json"
    path.write_text(json.dumps(result, indent=2))
    i, r, m = result["integration"], result["raycast"], result["memory"]
    print(f"device {vmap.device}: {args.scans} scans x 96 beams")
    print(f"integration  vogjax {i['vogjax_rays_per_s']:12,.0f} rays/s  octomap "
          f"{i['octomap_rays_per_s']:10,.0f} rays/s  speedup {i['speedup']:.1f}x")
    print(f"100k rays    vogjax {r['vogjax_s'] * 1e3:9.1f} ms       octomap {r['octomap_s'] * 1e3:9.1f} ms"
          f"       speedup {r['speedup']:.1f}x")
    print(f"memory       vogjax {m['vogjax_bytes'] / 2**20:9.1f} MiB      octomap "
          f"{m['octomap_bytes'] / 2**20:9.1f} MiB      ratio {m['ratio']:.2f}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
