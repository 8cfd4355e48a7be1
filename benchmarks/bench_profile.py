"""Where the map engine's time goes: per kernel and per host step, for integration, the 100k-ray
planner workload and full merges, with the machine's limits beside them. Writes JSON.

Kernel times: on the CPU a launch runs on the calling thread, so the thread's CPU time around
it is the kernel's (summed over the threads of a split launch); on CUDA, Warp's activity timing
(wp.timing_begin) gives the device times. Totals: wall time, and the process's CPU time (the
work done, whatever else shares the machine). Host steps: wall time of the named functions (they
include the kernels they launch). Limits: the copy bandwidth of this machine's memory, and the
plain voxel walk alone (count_beam_voxels), the work integration cannot avoid.

--baseline REF also times the same public calls with the code of git revision REF, in
subprocesses alternating with this tree's, and reports the ratios (new vs old, same machine,
same minutes).

    python benchmarks/bench_profile.py --out benchmarks/results [--scans 2000] [--submaps 100]
        [--repeats 3] [--baseline HEAD~3]
    python benchmarks/bench_profile.py --out benchmarks/results --pass-sweep 256,512,1024,2048 --scans 10000
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import functools
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def use_tree(root: Path) -> None:
    """Import vogjax (and its kernels and scenes) from the source tree at `root`."""
    mapping = {"vogjax": root / "vogjax", "vogjax.kernels": root / "kernels", "vogjax.scenes": root / "scenes"}

    class Finder:
        @classmethod
        def find_spec(cls, name, path=None, target=None):
            if name in mapping:
                return importlib.util.spec_from_file_location(
                    name, mapping[name] / "__init__.py", submodule_search_locations=[str(mapping[name])]
                )
            return None

    sys.meta_path.insert(0, Finder)


class Profile:
    """Records per-kernel CPU (or device) seconds and per-host-step wall seconds."""

    def __init__(self, wp, device):
        self.wp, self.device = wp, device
        self.kernels = collections.defaultdict(lambda: [0, 0.0])
        self.host = collections.defaultdict(lambda: [0, 0.0])
        self._launch = wp.launch

    def launch(self, kernel, *args, **kwargs):
        start = time.thread_time()
        result = self._launch(kernel, *args, **kwargs)
        entry = self.kernels[kernel.key]
        entry[0] += 1
        if not self.device.is_cuda:
            entry[1] += time.thread_time() - start
        return result

    def wrap(self, owner, name: str, label: str):
        real = getattr(owner, name)

        @functools.wraps(real)
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return real(*args, **kwargs)
            finally:
                entry = self.host[label]
                entry[0] += 1
                entry[1] += time.perf_counter() - start

        setattr(owner, name, timed)
        return real

    @contextlib.contextmanager
    def active(self, hooks: list):
        saved = [(owner, name, self.wrap(owner, name, label)) for owner, name, label in hooks]
        self.wp.launch = self.launch  # modules call wp.launch through the warp module
        try:
            yield self
        finally:
            self.wp.launch = self._launch
            for owner, name, real in saved:
                setattr(owner, name, real)

    def run(self, fn, repeats: int, hooks: list) -> dict:
        """Median wall, and per-kernel/host-step medians over `repeats` runs of fn."""
        walls, cpus, kernels, host = [], [], [], []
        for _ in range(repeats):
            self.kernels.clear()
            self.host.clear()
            with self.active(hooks):
                if self.device.is_cuda:
                    self.wp.timing_begin(cuda_filter=self.wp.TIMING_KERNEL)
                start, cpu = time.perf_counter(), time.process_time()
                fn()
                self.wp.synchronize()
                walls.append(time.perf_counter() - start)
                cpus.append(time.process_time() - cpu)
                if self.device.is_cuda:
                    for r in self.wp.timing_end():  # elapsed in milliseconds
                        self.kernels[r.name][1] += r.elapsed / 1e3
            kernels.append({k: tuple(v) for k, v in self.kernels.items()})
            host.append({k: tuple(v) for k, v in self.host.items()})
        # process CPU time (all threads): the work done, whatever else shares the machine
        return {
            "wall_s": float(np.median(walls)),
            "wall_runs_s": walls,
            "cpu_s": float(np.median(cpus)),
            "kernels": _medians(kernels, "cpu_s" if not self.device.is_cuda else "device_s"),
            "host": _medians(host, "wall_s"),
        }


def _medians(runs: list, field: str) -> dict:
    names = sorted({k for r in runs for k in r})
    return {
        k: {
            "calls": int(np.median([r.get(k, (0, 0.0))[0] for r in runs])),
            field: float(np.median([r.get(k, (0, 0.0))[1] for r in runs])),
        }
        for k in names
    }


def copy_bandwidth() -> float:
    """Bytes per second of a large NumPy copy (read + write), best of three."""
    a = np.ones(32 << 20)  # 256 MiB
    b = np.empty_like(a)
    best = min(_seconds(lambda: np.copyto(b, a)) for _ in range(3))
    return 2 * a.nbytes / best


def _seconds(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def one_thread(parallel):
    @contextlib.contextmanager
    def scope():
        old = parallel.MIN_ITEMS_PER_PART
        parallel.MIN_ITEMS_PER_PART = 1 << 62
        try:
            yield
        finally:
            parallel.MIN_ITEMS_PER_PART = old

    return scope()


def profile(args) -> dict:
    import warp as wp

    import vogjax as vj
    from vogjax.kernels import integration
    from vogjax.maps import blockmap, blocks, globalmap, integrator, parallel
    from vogjax.report.timing import planner_rays
    from vogjax.scenes import analytic

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_globalmap import build_dense_vog, build_vog

    cfg = vj.MapConfig()
    device = vj.VoxelMap(cfg, device=args.device).device
    prof = Profile(wp, device)
    sweep = analytic.orbit_sweep(analytic.pier(), args.scans)
    rays = sweep.points.shape[0]
    store_hooks = [
        (blocks.BlockStore, "ensure_blocks", "BlockStore.ensure_blocks"),
        (blocks.BlockStore, "find", "BlockStore.find"),
    ]

    def integrate():
        vmap = vj.VoxelMap(cfg, device=device)
        vmap.integrate_scans(sweep.origins, sweep.points, sweep.scan_index)
        return vmap

    vmap = integrate()  # compiles and loads the kernels
    hooks = [
        (integrator, "beams", "upload beams"),
        (integrator, "_boxes", "pass boxes"),
        (integrator, "_mark", "mark (launch, threads)"),
        (integrator, "_apply", "apply (blocks, launch)"),
        *store_hooks,
    ]
    result = {"device": str(device), "integration": prof.run(integrate, args.repeats, hooks)}
    counts = wp.empty(rays, dtype=wp.int32, device=device)
    batch = integrator.beams(device, sweep.origins, sweep.points, sweep.scan_index.astype(np.int32))

    def walk():
        wp.launch(
            integration.count_beam_voxels,
            dim=rays,
            inputs=[
                batch.origins,
                batch.points,
                batch.ray_scan,
                np.float64(cfg.max_range),
                np.float64(cfg.voxel_size),
                np.float64(1.0 / cfg.voxel_size),
            ],
            outputs=[counts],
            device=device,
        )

    walk()
    walks = [prof.run(walk, 1, []) for _ in range(args.repeats)]
    walk_s = min(
        w["kernels"]["count_beam_voxels"].get("cpu_s", w["wall_s"]) if not device.is_cuda else w["wall_s"]
        for w in walks
    )
    steps = int(counts.numpy().astype(np.int64).sum())
    it = result["integration"]
    it.update(
        {
            "rays": rays,
            "voxel_steps": steps,
            "voxel_steps_per_s": steps / it["wall_s"],
            "walk_only_s": walk_s,
            "walk_only_ns_per_step": walk_s / steps * 1e9,
        }
    )
    if not device.is_cuda:
        with one_thread(parallel):
            it["one_thread_wall_s"] = prof.run(integrate, args.repeats, [])["wall_s"]
        mark = it["kernels"].get("mark_beams", {}).get("cpu_s", 0.0)
        it["mark_ns_per_step"] = mark / steps * 1e9

    origins, directions = planner_rays(vmap, args.rays, np.random.default_rng(0))
    cast = lambda: vmap.raycast(origins, directions, 4.0)  # noqa: E731
    r = cast()
    ray_steps = int((r.num_free.astype(np.int64) + r.num_unknown + r.hit).sum())
    hooks = [
        (blockmap, "ray_arguments", "ray_arguments (validate, normalise)"),
        (blocks.BlockStore, "grid", "BlockStore.grid (cached)"),
    ]
    result["raycast"] = prof.run(cast, args.repeats, hooks)
    result["raycast"].update(
        {
            "rays": args.rays,
            "max_range_m": 4.0,
            "voxel_steps": ray_steps,
            "voxel_steps_per_s": ray_steps / result["raycast"]["wall_s"],
        }
    )
    if not device.is_cuda:
        with one_thread(parallel):
            result["raycast"]["one_thread_wall_s"] = prof.run(cast, args.repeats, [])["wall_s"]

    hooks = [
        (globalmap, "submap_views", "submap views"),
        (parallel, "disjoint_order", "thread phases (host)"),
        (globalmap.GlobalMap, "_contribute", "GlobalMap._contribute"),
        (globalmap.GlobalMap, "_refresh", "GlobalMap._refresh"),
        *store_hooks,
    ]
    for world, build in (("merge_pier", build_vog), ("merge_dense", build_dense_vog)):
        vog = build(args.submaps, device)
        merge = lambda: vj.GlobalMap(cfg, device=device).merge(vog)  # noqa: E731
        pulls = merge()
        result[world] = prof.run(merge, args.repeats, hooks)
        result[world].update(
            {"submaps": args.submaps, "voxel_updates": pulls, "voxel_updates_per_s": pulls / result[world]["wall_s"]}
        )
        if not device.is_cuda:
            with one_thread(parallel):
                result[world]["one_thread_wall_s"] = prof.run(merge, args.repeats, [])["wall_s"]
        if world == "merge_pier":
            result["planning"] = planning(prof, vj.GlobalMap(cfg, device=device), vog, args.repeats)
    return result


def planning(prof: Profile, global_map, vog, repeats: int) -> dict:
    """Next-best-view iterations with N_max 30 (a tree of about 30 nodes, 100k+ gain rays) on
    the pier's merged global map, from vehicle poses on its survey orbits."""
    from vogjax import planner
    from vogjax.config.planner import PlannerConfig
    from vogjax.geometry import pose_from_xyz_yaw
    from vogjax.planner import nbv, seen, source

    global_map.merge(vog)
    positions = vog.poses(range(0, vog.num_submaps, max(1, vog.num_submaps // 6)))[:, :3, 3]
    bounds = np.stack([positions.min(axis=0) - 3.0, positions.max(axis=0) + 3.0])
    starts = [pose_from_xyz_yaw(*p, np.arctan2(-p[1], -p[0])) for p in positions]  # facing the pier
    planner_ = planner.NbvPlanner(PlannerConfig(max_nodes=30), bounds=bounds)
    planner_.plan(global_map, starts[0])  # compiles the kernels
    plans = []

    def plan_all():
        for T in starts:
            planner_.reset()
            plans.append(planner_.plan(global_map, T))

    hooks = [
        (nbv, "clear_edges", "collision checks"),
        (nbv, "edge_counts", "edge gains"),
        (seen, "_launch", "gain pass (sets, launch, read-back)"),
        (source.Source, "candidates", "view candidates"),
        (source, "submap_views", "submap views"),
    ]
    out = prof.run(plan_all, repeats, hooks)
    out.update(
        {
            "iterations_per_run": len(starts),
            "rays_median": float(np.median([p.rays for p in plans])),
            "nodes_median": float(np.median([p.nodes for p in plans])),
            "plan_s_median": float(np.median([p.seconds for p in plans])),
        }
    )
    return out


def pass_sweep(args) -> dict:
    """Integration of the pier scans with each number of scans per pass (the mark scratch's
    budget lifted so no pass splits): median wall time, rays/s, and the scratch it took."""
    import vogjax as vj
    from vogjax.maps import integrator, voxelmap
    from vogjax.scenes import analytic

    cfg = vj.MapConfig()
    sweep = analytic.orbit_sweep(analytic.pier(), args.scans)
    device = vj.VoxelMap(cfg, device=args.device).device
    name = "SCANS_PER_PASS_CUDA" if device.is_cuda else "SCANS_PER_PASS"
    budget = "MARK_BUDGET_BYTES_CUDA" if device.is_cuda else "MARK_BUDGET_BYTES"
    saved = getattr(voxelmap, name), getattr(voxelmap, budget)
    rows = []
    try:
        setattr(voxelmap, budget, 1 << 40)
        for per_pass in [int(n) for n in args.pass_sweep.split(",")]:
            setattr(voxelmap, name, per_pass)
            integrator._pool.clear()  # each size grows its own scratch

            def integrate():
                vmap = vj.VoxelMap(cfg, device=device)
                vmap.integrate_scans(sweep.origins, sweep.points, sweep.scan_index)

            integrate()  # compiles, grows the scratch
            times = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                integrate()
                times.append(time.perf_counter() - start)
            scratch = sum(s.memory_bytes() for free in integrator._pool.values() for s in free)
            rows.append(
                {
                    "scans_per_pass": per_pass,
                    "seconds": float(np.median(times)),
                    "rays_per_s": sweep.points.shape[0] / float(np.median(times)),
                    "scratch_bytes": scratch,
                }
            )
            print(
                f"  {per_pass:6d} scans per pass: {rows[-1]['seconds'] * 1e3:8.1f} ms, "
                f"{rows[-1]['rays_per_s'] / 1e6:6.1f} M rays/s, scratch {scratch / 2**20:7.1f} MiB",
                flush=True,
            )
    finally:
        setattr(voxelmap, name, saved[0])
        setattr(voxelmap, budget, saved[1])
        integrator._pool.clear()
    return {"device": str(device), "scans": args.scans, "rays": int(sweep.points.shape[0]), "rows": rows}


def totals(args) -> dict:
    """Median seconds of the public calls only (any revision's code has them)."""
    import warp as wp

    import vogjax as vj
    from vogjax.scenes import analytic

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_globalmap import build_vog

    cfg = vj.MapConfig()
    sweep = analytic.orbit_sweep(analytic.pier(), args.scans)

    def timed(fn):
        fn()
        runs = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            fn()
            wp.synchronize()
            runs.append(time.perf_counter() - start)
        return float(np.median(runs))

    def integrate():
        vmap = vj.VoxelMap(cfg, device=args.device)
        vmap.integrate_scans(sweep.origins, sweep.points, sweep.scan_index)
        return vmap

    vmap = integrate()
    centres, values = vmap.voxels()
    rng = np.random.default_rng(0)
    free = centres[values <= cfg.log_free]
    origins = free[rng.integers(0, len(free), args.rays)]
    directions = rng.normal(size=origins.shape)
    vog = build_vog(args.submaps, args.device)
    calls = {
        "integration_s": integrate,
        "raycast_s": lambda: vmap.raycast(origins, directions, 4.0),
        "merge_pier_s": lambda: vj.GlobalMap(cfg, device=args.device).merge(vog),
    }
    result = {name: timed(call) for name, call in calls.items()}
    from vogjax.maps import parallel  # both revisions split CPU launches there

    with one_thread(parallel):  # per core: robust to other work on the machine
        result.update({f"one_thread_{name}": timed(call) for name, call in calls.items()})
    return result


def baseline(args) -> dict:
    """This tree against revision args.baseline: totals() in alternating subprocesses."""
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", args.baseline], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        command = [
            sys.executable,
            str(Path(__file__).resolve()),
            "--totals",
            "--scans",
            str(args.scans),
            "--submaps",
            str(args.submaps),
            "--rays",
            str(args.rays),
            "--repeats",
            str(args.repeats),
        ]
        runs = {"old": [], "new": []}
        for _ in range(args.rounds):
            for side, tree in (("old", tmp), ("new", str(ROOT))):
                out = subprocess.run(
                    [*command, "--tree", tree],
                    check=True,
                    capture_output=True,
                    text=True,
                    env={**os.environ, "TQDM_DISABLE": "1"},
                ).stdout
                runs[side].append(json.loads(out.strip().splitlines()[-1]))
    keys = runs["new"][0].keys()
    return {
        "revision": args.baseline,
        "rounds": args.rounds,
        "old_s": {k: float(np.median([r[k] for r in runs["old"]])) for k in keys},
        "new_s": {k: float(np.median([r[k] for r in runs["new"]])) for k in keys},
        "speedup": {k: float(np.median([o[k] / n[k] for o, n in zip(runs["old"], runs["new"])])) for k in keys},
        "runs": runs,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--scans", type=int, default=2000)
    parser.add_argument("--rays", type=int, default=100_000)
    parser.add_argument("--submaps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=3, help="alternations with --baseline")
    parser.add_argument("--baseline", default=None, help="git revision to compare with")
    parser.add_argument("--device", default=None)
    parser.add_argument(
        "--pass-sweep",
        default=None,
        help="comma-separated scans per pass: time integration with each (writes pass_sweep_DEVICE.json)",
    )
    parser.add_argument("--totals", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--tree", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.tree is not None:
        use_tree(args.tree.resolve())
    if args.totals:
        print(json.dumps(totals(args)))
        return
    if args.pass_sweep:
        result = pass_sweep(args)
        args.out.mkdir(parents=True, exist_ok=True)
        path = args.out / f"pass_sweep_{result['device'].split(':')[0]}.json"
        path.write_text(json.dumps(result, indent=2))
        print(f"wrote {path}")
        return
    import warp as wp

    result = profile(args)
    device = result.pop("device")
    result = {
        "machine": {
            "device": device,
            "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count(),
            "warp": wp.__version__,
            "copy_bandwidth_bytes_per_s": copy_bandwidth(),
            "load_average": list(os.getloadavg()),
        },
        "scans": args.scans,
        "submaps": args.submaps,
        "repeats": args.repeats,
        **result,
    }
    if args.baseline:
        result["baseline"] = baseline(args)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"profile_{device.split(':')[0]}.json"
    path.write_text(json.dumps(result, indent=2))
    _print(result)
    print(f"wrote {path}")


def _print(result: dict) -> None:
    m = result["machine"]
    print(
        f"{m['device']}, {m['cores']} cores, copy bandwidth {m['copy_bandwidth_bytes_per_s'] / 1e9:.1f} GB/s, "
        f"load {m['load_average'][0]:.1f}"
    )
    for section in ("integration", "raycast", "merge_pier", "merge_dense", "planning"):
        s = result[section]
        one = f", one thread {s['one_thread_wall_s'] * 1e3:.1f} ms" if "one_thread_wall_s" in s else ""
        print(f"{section}: {s['wall_s'] * 1e3:.1f} ms (CPU {s['cpu_s'] * 1e3:.1f} ms){one}")
        for name, k in sorted(s["kernels"].items(), key=lambda kv: -list(kv[1].values())[1]):
            print(f"    kernel {name:28s} {list(k.values())[1] * 1e3:9.2f} ms  ({k['calls']} launches)")
        for name, h in sorted(s["host"].items(), key=lambda kv: -kv[1]["wall_s"]):
            print(f"    host   {name:28s} {h['wall_s'] * 1e3:9.2f} ms  ({h['calls']} calls)")
    p = result["planning"]
    print(
        f"planning: {p['plan_s_median'] * 1e3:.1f} ms per iteration (median), {p['rays_median']:,.0f} gain rays, "
        f"{p['nodes_median']:.0f} nodes"
    )
    it = result["integration"]
    mark = f", mark_beams {it['mark_ns_per_step']:.2f} ns/step (CPU)" if "mark_ns_per_step" in it else ""
    print(
        f"integration: {it['voxel_steps'] / 1e6:.1f} M voxel steps, {it['voxel_steps_per_s'] / 1e6:.0f} M/s; "
        f"plain walk alone {it['walk_only_ns_per_step']:.2f} ns/step{mark}"
    )
    if "baseline" in result:
        b = result["baseline"]
        for k, v in b["speedup"].items():
            print(
                f"vs {b['revision']}: {k} old {b['old_s'][k] * 1e3:.1f} ms new {b['new_s'][k] * 1e3:.1f} ms "
                f"speedup {v:.2f}x"
            )


if __name__ == "__main__":
    main()
