"""The batch pipeline on a simulated propeller survey of 150 submaps: scans per second against
the sonar's real-time rate, and where the time goes; then the planner workload on the final maps
(100k planner rays, next-best-view planning iterations on the global and on the virtual map, and
view-gain rays per second). Writes JSON.

    python benchmarks/bench_pipeline.py --out benchmarks/results [--submaps 150] [--run RUN.h5]

--run maps the first scans of an existing propeller run instead of simulating one (on a GPU
machine this saves the simulation's compile time).
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from vogjax import pipeline, planner, scenes
from vogjax.config import SonarConfig
from vogjax.config.pipeline import TimingConfig
from vogjax.config.planner import PlannerConfig
from vogjax.geometry import pose_from_xyz_yaw
from vogjax.io.dataset import Dataset, DatasetWriter
from vogjax.report.timing import planner_rays
from vogjax.sensors import ProfilingSonar

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
    parser.add_argument("--run", type=Path, default=None, help="map this propeller run instead of simulating one")
    parser.add_argument(
        "--slam-thread",
        action="store_true",
        help="also map with SLAM on a second thread (slam_thread on against off, alternating), checking the same bits",
    )
    args = parser.parse_args()
    scans = args.submaps * args.scans_per_submap
    # no timing probes: their full merges and queries would count in the pipeline's wall time
    config = pipeline.PipelineConfig(scans_per_submap=args.scans_per_submap, timing=TimingConfig(every_submaps=0))
    with tempfile.TemporaryDirectory() as folder:
        run_path = Path(folder) / "propeller.h5"
        if args.run is None:  # the lawn-mower survey flown until it has enough scans (about 2000 per lap)
            from vogjax.sim import simulate_run  # MuJoCo only when simulating

            simulate_run(
                "propeller",
                run_path,
                laps=scans // 1500 + 1,
                num_scans=scans,
                sensor=SonarConfig(range_noise_m=0.02),
                progress=False,
            )
        else:
            _prefix(args.run, run_path, scans)
        with Dataset(run_path) as run:
            num_scans = len(run)
            poses_nav = run.read(0, num_scans).pose_nav
        # warm-up on a short prefix: kernels compiled and loaded before timing
        pipeline.run(_prefix(run_path, Path(folder) / "warm.h5", 3 * args.scans_per_submap), config, progress=False)
        start = time.perf_counter()
        result = pipeline.run(run_path, config)
        seconds = time.perf_counter() - start
        threads = slam_thread_comparison(run_path, config, result) if args.slam_thread else None
    origins, directions = planner_rays(result.global_map, args.rays)
    result.global_map.raycast(origins[:16], directions[:16], 4.0)
    start = time.perf_counter()
    result.global_map.raycast(origins, directions, 4.0)
    query_s = time.perf_counter() - start
    planning = planner_workload(result, poses_nav)
    steps = {name: float(sum(np.sum(result.timings.get(t, 0.0)) for t in names)) for name, names in STEPS.items()}
    survey_s = num_scans / SonarConfig().rate_hz
    ate = result.metrics["trajectory_rmse_m"]
    device = str(result.global_map.device)
    report = {
        "machine": {"device": device, "cpu": platform.machine(), "python": platform.python_version()},
        "scene": "propeller",
        "scans": num_scans,
        "submaps": result.vog.num_submaps,
        "survey_s": survey_s,
        "seconds": seconds,
        "scans_per_s": num_scans / seconds,
        "real_time_factor": survey_s / seconds,
        "steps_s": steps,
        "steps_fraction": {k: v / seconds for k, v in steps.items()},
        "slam_ms_per_submap": slam_per_submap_ms(result),
        # "auto" puts SLAM on a second thread with two or more cores: its steps then share them
        "slam_on_second_thread": result.slam_on_second_thread,
        "slam_thread": threads,
        "reapplied_submaps": int(np.sum(result.timings["reapplied"])),
        "loop_closures": {"accepted": len(result.loop_closures), "rejected": len(result.rejected)},
        "trajectory_rmse_m": ate,
        "query_rays": args.rays,
        "query_s": query_s,
        "planner": planning,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    name = f"pipeline_{device.split(':')[0]}.json"
    (args.out / name).write_text(json.dumps(report, indent=2))
    print(
        f"{num_scans} scans, {result.vog.num_submaps} submaps on {device}: {seconds:.1f} s, "
        f"{num_scans / seconds:,.0f} scans/s = {survey_s / seconds:.0f}x real time (5 Hz sonar)"
    )
    slam = report["slam_ms_per_submap"]
    beside = " (on a second thread, sharing the cores with the map work)" if report["slam_on_second_thread"] else ""
    print(f"  SLAM steps per submap{beside}: median {slam['median']:.1f} ms, mean {slam['mean']:.1f} ms")
    for key, value in sorted(steps.items(), key=lambda kv: -kv[1]):
        print(f"  {key:22s} {value:7.2f} s  {value / seconds:5.1%}")
    print(f"  {args.rays:,} planner rays on the final global map: {query_s * 1e3:.1f} ms")
    print(
        f"  loop closures {len(result.loop_closures)} accepted, {len(result.rejected)} rejected; "
        f"trajectory RMSE navigation {ate['navigation']:.2f} m, optimised {ate['optimized']:.2f} m"
    )
    for name_, arm in planning["plans"].items():
        print(
            f"  planning iteration on the {name_:28s} median {arm['plan_s_median'] * 1e3:8.1f} ms, "
            f"{arm['rays_median']:,.0f} gain rays, {arm['nodes_median']:.0f} nodes"
        )
    for name_, gain in planning["view_gain"].items():
        print(f"  view_gain on the {name_:7s} map: {gain['rays_per_s']:,.0f} rays/s ({gain['rays']:,} rays)")
    print(f"wrote {args.out / name}")


def slam_per_submap_ms(result) -> dict:
    """Median and mean (ms) of each submap's SLAM steps: the pose graph's updates and marginals
    (isam2) and the loop-closure detector."""
    steps = np.asarray(result.timings["isam2"]) + np.asarray(result.timings["loop_closure"])
    return {"median": float(np.median(steps)) * 1e3, "mean": float(np.mean(steps)) * 1e3}


def slam_thread_comparison(run_path: Path, config, reference, repeats: int = 2) -> dict:
    """The same run with slam_thread "on" and "off", alternating: wall times and whether every
    pose and the global map are the same bits as `reference` (the default run)."""
    walls = {"off": [], "on": []}
    same = True
    for _ in range(repeats):
        for flag in ("off", "on"):
            start = time.perf_counter()
            result = pipeline.run(run_path, config.replace(slam_thread=flag), progress=False)
            walls[flag].append(time.perf_counter() - start)
            same &= np.array_equal(result.optimized, reference.optimized) and all(
                np.array_equal(a, b) for a, b in zip(result.global_map.sums(), reference.global_map.sums())
            )
    out = {flag: {"seconds": w, "median_s": float(np.median(w))} for flag, w in walls.items()}
    out["off_over_on"] = out["off"]["median_s"] / out["on"]["median_s"]
    out["same_bits"] = bool(same)
    print(
        f"  SLAM on a second thread: {out['on']['median_s']:.1f} s against {out['off']['median_s']:.1f} s in order "
        f"({out['off_over_on']:.2f}x), same bits: {same}"
    )
    return out


def planner_workload(result, poses_nav: np.ndarray, iterations: int = 10) -> dict:
    """Next-best-view planning on the final maps from poses along the survey (Table 4.2's
    settings; also with N_max 30, a tree twice the size), and view-gain rays per second."""
    scene = scenes.load("propeller")
    sensor = ProfilingSonar(SonarConfig(range_noise_m=0.02))
    lo, hi = scene.bounds[0] + 1.0, scene.bounds[1] - 1.0
    picks = np.linspace(0, len(poses_nav) - 1, iterations).astype(int)
    starts = [
        pose_from_xyz_yaw(*np.clip(poses_nav[i, :3, 3], lo, hi), np.arctan2(poses_nav[i, 1, 0], poses_nav[i, 0, 0]))
        for i in picks
    ]
    maps = {"global": result.global_map, "virtual": result.vog}
    arms = {
        "global map": ("global", PlannerConfig(), iterations),
        "global map, N_max 30": ("global", PlannerConfig(max_nodes=30), iterations),
        "virtual map": ("virtual", PlannerConfig(), 3),
    }
    plans = {}
    for name, (kind, config, count) in arms.items():
        nbv = planner.NbvPlanner(config, bounds=scene.bounds, sensor=sensor, region=scene.region())
        nbv.plan(maps[kind], starts[0])  # compiles the kernels
        runs = []
        for T in starts[:count]:
            nbv.reset()  # every iteration a fresh tree: the same work for every map
            runs.append(nbv.plan(maps[kind], T))
        plans[name] = {
            "iterations": count,
            "plan_s": [p.seconds for p in runs],
            "plan_s_median": float(np.median([p.seconds for p in runs])),
            "rays_median": float(np.median([p.rays for p in runs])),
            "nodes_median": float(np.median([p.nodes for p in runs])),
        }
    rng = np.random.default_rng(0)
    box = np.stack([scene.bounds[0] + 0.5, scene.bounds[1] - 0.5])
    views = np.array([pose_from_xyz_yaw(*rng.uniform(*box), rng.uniform(-np.pi, np.pi)) for _ in range(200)])
    views = views @ sensor.T_vehicle_sensor
    gains = {}
    for kind, m in maps.items():
        timed = []
        for _ in range(3):
            start = time.perf_counter()
            gain = planner.view_gain(m, views, sensor, max_range_m=PlannerConfig().gain_range_m, region=scene.region())
            timed.append(time.perf_counter() - start)
        gains[kind] = {
            "views": len(views),
            "rays": int(gain.rays),
            "seconds": float(np.median(timed)),
            "rays_per_s": gain.rays / float(np.median(timed)),
        }
    return {"plans": plans, "view_gain": gains}


def _prefix(path: Path, out: Path, scans: int) -> Path:
    """A copy of the first `scans` scans of a run."""
    with Dataset(path) as ds:
        batch = ds.read(0, scans)
        with DatasetWriter(out, batch.ranges.shape[1], ds.metadata) as writer:
            writer.append(
                **{
                    name: getattr(batch, name)
                    for name in (
                        "time_s",
                        "pose_truth",
                        "pose_nav",
                        "sonar_origin",
                        "sonar_directions",
                        "ranges",
                        "no_return",
                        "invalid",
                    )
                }
            )
    return out


if __name__ == "__main__":
    main()
