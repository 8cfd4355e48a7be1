"""OctoMap parity: planner rays at coarse levels, the cost of keeping levels, loading .bt/.ot files.

Measures, in one run and side by side:
- rays: 100k planner rays (origins at free voxel centres, random directions) on a sonar map of
  the pier at levels 0-3: time (median of --repeats) and agreement with level 0 (same hit or
  miss; coarse hits at or before level 0's; rays where level 0 hits and the coarse cast does
  not, or later: must be 0);
- maintenance: the same scans integrated one call per scan (and per 100 scans) into six maps
  at once, interleaved: no levels, levels 1-3 or 1-6 kept and brought up to date every 1, 10
  or 100 scans; and what building levels from
  scratch costs instead; a global map's merge and update_poses with and without levels 1-3;
- loading: a .bt and a .ot of a few million voxels, vogjax's VoxelMap.from_octomap against
  octomap-python's OcTree.readBinary / OcTree.read (medians of --repeats, kernels compiled).

    python benchmarks/bench_octomap.py --out benchmarks/results [--scans 1500] [--rays 100000]

On a loaded machine, `--cpu-time` times the process's CPU seconds instead of wall seconds (a
job preempted by others is not charged for their turn), and `--sections rays,maintenance` runs
only those sections (printed as JSON on stdout, no results file written): how the ray-cast and
level-maintenance figures were compared against the main branch's code, run alternately.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp
from tqdm import tqdm

import vogjax as vj
from vogjax.io import octomap as om
from vogjax.io.octomap_read import read_octree
from vogjax.pipeline.probes import planner_rays
from vogjax.scenes import analytic

RAY_LENGTHS_M = (5.0, 11.0)  # the planner's gain range, and the sonar's reach
SECTIONS = ("maintenance", "rays", "builds", "global", "loading", "exploration")
CLOCK = time.perf_counter  # the timer of every measurement (--cpu-time: time.process_time)


def timed(call, repeats: int = 1):
    """(median seconds, every run's seconds, the last result) of `repeats` calls."""
    runs, result = [], None
    for _ in range(repeats):
        start = CLOCK()
        result = call()
        wp.synchronize()
        runs.append(CLOCK() - start)
    return statistics.median(runs), runs, result


def pier_scans(num_scans: int):
    """Sonar scans (96 beams) orbiting the pier at three radii: origins (S,3), points, scan index."""
    scene = analytic.pier()
    parts = []
    for lap, radius in enumerate((7.0, 8.5, 10.0)):
        sweep = analytic.orbit_sweep(scene, num_scans // 3, radius_m=radius, depths_m=(2.0 + lap, 3.0), seed=lap)
        parts.append(sweep)
    origins = np.concatenate([p.origins for p in parts]).astype(np.float32)
    points = np.concatenate([p.points for p in parts]).astype(np.float32)
    offsets = np.cumsum([0] + [len(p.origins) for p in parts[:-1]])
    scan = np.concatenate([p.scan_index + o for p, o in zip(parts, offsets)])
    return origins, points, scan


def warm_up(origins, points, scan, device) -> None:
    """Every kernel compiled and loaded before anything is timed."""
    for levels in (0, 6):
        vmap = vj.VoxelMap(vj.MapConfig(), device=device)
        for k in range(3):
            rows = scan == k
            vmap.integrate_scans(origins[k : k + 1], points[rows], scan[rows] - k)
            vmap.store_at(levels)
        for level in range(4):
            vmap.raycast(origins[:4].astype(np.float64), np.ones((4, 3)), 5.0, level=level)
    gmap = vj.GlobalMap(vmap.config, device=device)
    gmap.store_at(3)
    vog = vj.VogMap(vmap.config, device=device)
    vog.add_submap(np.eye(4))
    vog.submap(0).integrate_scans(origins[:1], points[scan == 0], scan[scan == 0])
    gmap.merge(vog)
    gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0)
    gmap.store_at(3)


def maintenance(origins, points, scan, device, chunk: int) -> tuple[dict, list]:
    """Integrate the scans `chunk` per call into six maps, interleaved call by call (the order
    rotating, so load on the machine hits all alike): one keeping no levels, and ones keeping
    levels 1-3 or 1-6 brought up to date (what a coarse query does first) after every call,
    after every 10 scans (levels 1-3) or after every 100 scans (a planning iteration). Their
    time includes that update."""
    kinds = [(0, 0), (3, 1), (3, 10), (3, 100), (6, 1), (6, 100)]  # (levels kept, scans between updates)
    maps = [vj.VoxelMap(vj.MapConfig(), device=device) for _ in kinds]
    for vmap, (levels, _) in zip(maps, kinds):
        if levels:
            vmap.store_at(levels)  # built (empty) now, kept from here on
    seconds = [0.0] * len(kinds)
    starts = np.searchsorted(scan, np.arange(0, scan.max() + 1, chunk))
    bounds = list(zip(starts, [*starts[1:], len(scan)]))
    for k, (lo, hi) in enumerate(tqdm(bounds, desc=f"integrating {chunk} scan(s) a call", unit="call")):
        rows = slice(lo, hi)
        first = scan[lo]
        part = scan[rows] - first
        done = int(scan[hi - 1]) + 1  # scans integrated after this call
        for j in range(len(kinds)):
            m = (j + k) % len(kinds)
            levels, every = kinds[m]
            start = CLOCK()
            maps[m].integrate_scans(origins[first : first + part.max() + 1], points[rows], part)
            if levels and (done % every == 0 or hi == len(scan) or every <= chunk):
                maps[m].store_at(levels)
            wp.synchronize()
            seconds[m] += CLOCK() - start
    scans = int(scan.max() + 1)
    base = seconds[0]
    row = {"scans_per_call": chunk, "calls": len(bounds), "ms_per_scan": {}, "overhead_percent": {}}
    for (levels, every), total in zip(kinds, seconds):
        name = f"levels_1-{levels}_updated_every_{max(every, chunk)}_scans" if levels else "no_levels"
        row["ms_per_scan"][name] = 1e3 * total / scans
        if levels:
            row["overhead_percent"][name] = 100.0 * (total - base) / base
    for (levels, _), vmap in zip(kinds[1:], maps[1:]):  # what was kept equals a fresh build
        fresh = vj.VoxelMap(vmap.config, device=device)
        fresh._store = maps[0].store
        for level in range(1, levels + 1):
            a, b = vmap.voxels(level), fresh.voxels(level)
            assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), f"level {level} differs"
    return row, maps


def rays_by_level(vmap, count: int, repeats: int, lengths=RAY_LENGTHS_M, levels=range(4)) -> list:
    """The same rays cast at each level: the levels take turns within each of `repeats` rounds
    (the first level rotating), so a change of load on the machine hits every level alike; the
    speed-up is the median over rounds of each round's level-0 time over the level's."""
    origins, directions = planner_rays(vmap, count, rng=0)
    levels = list(levels)
    rows = []
    for length in lengths:
        results, runs = {}, {level: [] for level in levels}
        for level in levels:
            vmap.raycast(origins[:16], directions[:16], length, level=level)  # kernels loaded, tables built
        for round_ in range(repeats):
            for k in range(len(levels)):
                level = levels[(k + round_) % len(levels)]
                cast = lambda level=level: vmap.raycast(origins, directions, length, level=level)  # noqa: E731
                seconds, _, results[level] = timed(cast)
                runs[level].append(seconds)
        fine = results[0]
        hits = fine.hit
        for level in levels:
            result = results[level]
            later = hits & (~result.hit | (result.distance > fine.distance + 1e-5))
            ratios = [a / b for a, b in zip(runs[0], runs[level])]
            rows.append(
                {
                    "ray_length_m": length,
                    "level": level,
                    "voxel_m": vmap.config.voxel_size * 2**level,
                    "seconds": statistics.median(runs[level]),
                    "runs_s": runs[level],
                    "speedup_vs_level_0": statistics.median(ratios),
                    "speedup_range": [min(ratios), max(ratios)],
                    "same_hit_or_miss": float(np.mean(result.hit == fine.hit)),
                    "hit_fraction": float(result.hit.mean()),
                    "level_0_hits_missed_or_later": int(later.sum()),
                    "mean_distance_shortfall_m": float(np.mean((fine.distance - result.distance)[hits]))
                    if hits.any()
                    else 0.0,
                    "mean_voxels_walked": float(np.mean(result.num_free + result.num_unknown)),
                }
            )
    return rows


def build_costs(vmap, device, repeats: int) -> dict:
    """Levels built from scratch on a map holding none (the alternative to keeping them)."""
    out = {}
    for n in (3, 6):

        def build(n=n):
            fresh = vj.VoxelMap(vmap.config, device=device)
            fresh._store = vmap.store
            fresh.store_at(n)

        out[f"levels_1-{n}_s"] = timed(build, repeats)[0]
    return out


def global_costs(origins, points, scan, device, repeats: int) -> dict:
    """Submaps of 100 scans; merge and update_poses (5 submaps re-applied) with and without
    levels 1-3, interleaved."""
    cfg = vj.MapConfig()
    vog = vj.VogMap(cfg, device=device)
    for first in range(0, int(scan.max()) + 1, 100):
        rows = (scan >= first) & (scan < first + 100)
        pose = np.eye(4)
        pose[:3, 3] = origins[first]
        i = vog.add_submap(pose)
        part = scan[rows] - first
        vog.submap(i).integrate_scans(
            origins[first : first + part.max() + 1] - pose[:3, 3], points[rows] - pose[:3, 3], part
        )
    maps = {n: vj.GlobalMap(cfg, device=device) for n in (0, 3)}
    maps[3].state(np.zeros((1, 3)), level=3)
    result = {"submaps": vog.num_submaps}
    for n, gmap in maps.items():
        result[f"merge_levels_{n}_s"] = timed(lambda gmap=gmap: gmap.merge(vog), repeats)[0]
    rng = np.random.default_rng(1)
    home = vog.poses()
    runs = {0: [], 3: []}
    for _ in range(repeats):
        ids = rng.choice(vog.num_submaps, min(5, vog.num_submaps), replace=False)
        moved = home[ids].copy()
        moved[:, :3, 3] += rng.normal(0, 0.05, (len(ids), 3))
        vog.set_poses(ids, moved)
        for n, gmap in maps.items():
            runs[n].append(timed(lambda gmap=gmap: gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0))[0])
        vog.set_poses(ids, home[ids])
        for gmap in maps.values():
            gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0)
    for n in runs:
        result[f"update_poses_5_submaps_levels_{n}_s"] = statistics.median(runs[n])
    fresh = vj.GlobalMap(cfg, device=device)
    fresh.merge(vog)
    for level in (1, 2, 3):
        a, b = maps[3].voxels(level), fresh.voxels(level)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), f"global level {level} differs"
    return result


def loading(target_voxels: int, device, repeats: int, folder: Path, rays: int) -> dict:
    import octomap

    rng = np.random.default_rng(2)
    cfg = vj.MapConfig(max_range=20.0)
    vmap = vj.VoxelMap(cfg, device=device)
    while len(vmap.voxels()[0]) < target_voxels:
        vmap.integrate_scans(*_random_scans(rng, 10, 2000))
    result = {"voxels": len(vmap.voxels()[0])}
    # a larger map, whose box holds the rays' whole walk: the walks, not the rays' set-up, dominate
    result["ray_casts"] = rays_by_level(vmap, rays, repeats, lengths=(11.0,))
    result["levels_built_from_scratch"] = build_costs(vmap, device, repeats)
    for format in ("bt", "ot"):
        path = folder / f"map.{format}"
        nodes = om.save(vmap, path)
        ours = read_octree(path)
        vj.VoxelMap.from_octomap(path, device=device)  # kernels compiled
        seconds, runs, loaded = timed(lambda path=path: vj.VoxelMap.from_octomap(path, device=device), repeats)
        if format == "bt":
            theirs_s, theirs_runs, tree = timed(lambda path=path: _read_binary(octomap, cfg, path), repeats)
        else:
            theirs_s, theirs_runs, tree = timed(lambda path=path: octomap.OcTree.read(str(path).encode()), repeats)
        assert tree.size() == nodes == ours.nodes and tree.getNumLeafNodes() == len(ours)
        result[format] = {
            "bytes": path.stat().st_size,
            "nodes": nodes,
            "leaves": len(ours),
            "voxels_read": len(loaded.voxels()[0]),
            "vogjax_s": seconds,
            "vogjax_runs_s": runs,
            "octomap_python_s": theirs_s,
            "octomap_python_runs_s": theirs_runs,
            "speedup": theirs_s / seconds,
        }
    return result


def _read_binary(octomap, cfg, path):
    tree = octomap.OcTree(cfg.voxel_size)
    tree.readBinary(str(path).encode())
    return tree


def _random_scans(rng, scans: int, beams: int):
    origins = rng.uniform(-1, 1, (scans, 3)).astype(np.float32)
    directions = rng.normal(size=(scans * beams, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ranges = rng.uniform(0.5, 18.0, scans * beams)
    points = np.repeat(origins, beams, axis=0) + directions * ranges[:, None]
    return origins, points.astype(np.float32), np.repeat(np.arange(scans), beams)


EXPLORE_LEVELS = ((0, 0), (1, 1), (2, 2), (2, 0))  # (collision_level, gain_level)


def exploration(submaps: int, levels=EXPLORE_LEVELS, folder: Path | None = None) -> list:
    """The propeller explored on the navigation-only VoxelMap ("standard": the planner's map is
    one VoxelMap, level 0 and its coarse levels alike) with the planner's collision checks and
    gain rays at the levels given ((collision_level, gain_level) pairs): plan time and explored
    volume (known voxels of the scene's region in the global map) against mission time."""
    import csv

    from vogjax.sim.explore import explore, scene_planner

    rows = []
    for collision, gain in levels:
        config = scene_planner("propeller", 0).replace(collision_level=collision, gain_level=gain)
        out = Path(folder) / f"explore_levels{collision}{gain}.h5"
        start = time.perf_counter()
        summary = explore("propeller", out, submaps=submaps, map_kind="standard", planner_config=config, progress=False)
        wall = time.perf_counter() - start
        with open(summary.csv_path) as f:
            table = list(csv.DictReader(f))
        plan_s = [float(r["plan_s"]) for r in table]
        rows.append(
            {
                "collision_level": collision,
                "gain_level": gain,
                "submaps": summary.submaps,
                "scans": summary.scans,
                "iterations": summary.iterations,
                "stopped": summary.stopped,
                "mission_s": summary.duration_s,
                "path_m": summary.path_m,
                "explored_m3": summary.explored_m3,
                "plan_s_median": statistics.median(plan_s) if plan_s else None,
                "plan_s_total": sum(plan_s),
                "rays_median": statistics.median(float(r["rays"]) for r in table) if table else None,
                "wall_s": wall,
                "explored_m3_by_time": [[float(r["time_s"]), float(r["explored_m3"])] for r in table],
            }
        )
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--scans", type=int, default=1500)
    parser.add_argument("--rays", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--bt-voxels", type=int, default=3_000_000)
    parser.add_argument("--explore-submaps", type=int, default=20, help="0: no exploration runs")
    parser.add_argument("--device", default=None)
    parser.add_argument("--cpu-time", action="store_true", help="time CPU seconds of the process, not wall seconds")
    parser.add_argument(
        "--sections", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}"
    )
    args = parser.parse_args()
    sections = args.sections.split(",")
    if unknown := set(sections) - set(SECTIONS):
        parser.error(f"--sections: unknown {', '.join(sorted(unknown))} (choose from {', '.join(SECTIONS)})")
    global CLOCK
    if args.cpu_time:
        CLOCK = time.process_time
    device = vj.VoxelMap(device=args.device).device
    origins, points, scan = pier_scans(args.scans)
    warm_up(origins, points, scan, device)
    if set(sections) != set(SECTIONS):  # a partial run: its figures on stdout, no results file
        per_scan, maps = maintenance(origins, points, scan, device, chunk=1)
        partial = {"clock": CLOCK.__name__, "load_average": list(os.getloadavg())}
        if "maintenance" in sections:
            partial["maintenance"] = [per_scan, maintenance(origins, points, scan, device, chunk=100)[0]]
        if "rays" in sections:
            partial["ray_casts"] = rays_by_level(maps[0], args.rays, args.repeats)
        print(json.dumps(partial, indent=1))
        return
    per_scan, maps = maintenance(origins, points, scan, device, chunk=1)
    per_batch, _ = maintenance(origins, points, scan, device, chunk=100)
    vmap = maps[0]
    rays = rays_by_level(vmap, args.rays, args.repeats)
    builds = build_costs(vmap, device, args.repeats)
    global_map = global_costs(origins, points, scan, device, args.repeats)
    with tempfile.TemporaryDirectory() as folder:
        load = loading(args.bt_voxels, device, args.repeats, Path(folder), args.rays)
        explored = exploration(args.explore_submaps, folder=Path(folder)) if args.explore_submaps else []
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    result = {
        "date": time.strftime("%Y-%m-%d"),
        "commit": commit,
        "machine": {
            "device": str(device),
            "cpu": platform.machine(),
            "cores": os.cpu_count(),
            "python": platform.python_version(),
            "warp": wp.__version__,
            "load_average": list(os.getloadavg()),
        },
        "scene": f"pier, {int(scan.max()) + 1} sonar scans (96 beams, 11 m) orbiting at 7-10 m",
        "voxel_size_m": vmap.config.voxel_size,
        "map_voxels": len(vmap.voxels()[0]),
        "rays": args.rays,
        "repeats": args.repeats,
        "ray_casts": rays,
        "maintenance": [per_scan, per_batch],
        "levels_built_from_scratch": builds,
        "global_map": global_map,
        "loading": load,
        "exploration": explored,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    name = "octomap_cuda.json" if device.is_cuda else "octomap_cpu.json"
    (args.out / name).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("maintenance", "levels_built_from_scratch", "global_map")}, indent=1))
    for r in rays:
        print(
            f"{r['ray_length_m']:4.0f} m level {r['level']}: {r['seconds'] * 1e3:7.1f} ms "
            f"({r['speedup_vs_level_0']:.2f}x), same hit/miss {r['same_hit_or_miss']:.3f}, "
            f"level-0 hits missed or later {r['level_0_hits_missed_or_later']}"
        )
    for r in explored:
        print(
            f"explore levels {r['collision_level']}/{r['gain_level']}: {r['explored_m3']:.1f} m^3 in "
            f"{r['mission_s']:.0f} s mission, {r['iterations']} plans, "
            f"median plan {(r['plan_s_median'] or 0) * 1e3:.0f} ms"
        )
    for format in ("bt", "ot"):
        r = load[format]
        print(
            f".{format}: {r['voxels_read']} voxels, vogjax {r['vogjax_s']:.2f} s, "
            f"octomap-python {r['octomap_python_s']:.2f} s"
        )


if __name__ == "__main__":
    main()
