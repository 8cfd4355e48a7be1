"""Closed-loop exploration with the next-best-view planner, reproducing the papers' figures.

1. rmse (Ho thesis Table 4.3, IROS Table II): the propeller explored with Table 4.2's
   parameters (0.095 m voxels, 100 scans per submap, 2 m edges, lambda 0.5, N_max 15, planner
   range 5 m, 1 x 1 x 0.5 m box) and the thesis's drift (Eq. 4.1), `--runs` runs per arm: the
   planner on the standard (navigation-only) map, and on the online global map with loop
   closures. Reconstruction RMSE after registration of the standard map, of the virtual map at
   navigation poses (without loop closures) and of the online global map (with loop closures),
   with the share of the true surface each covers, and per seed whether they fall in the
   thesis's order. Every run is also checked for collisions of the true path's box with the
   true mesh.
2. timing (Sodhi Fig. 8 with the planner's own queries): in the first global-map run, every
   `--timing-every` submaps, the same planning iteration on the online global map and on the
   virtual map side by side (a fresh planner, same seed), and the median time per gain ray of a
   fixed batch of views on each.
3. volume: explored volume (known voxels of the scene's region, from the true poses) against
   mission time and path length for every exploration run, and for the scripted survey of
   `vogjax simulate` over as many scans.

    python benchmarks/bench_explore.py --out benchmarks/results [--submaps 156] [--runs 2]
    python benchmarks/bench_explore.py --out benchmarks/results --reuse /tmp/bench_runs

`--reuse DIR` takes every ARM_SEED.h5 with its ARM_SEED.explore.csv found in DIR (as `--keep`
leaves them) instead of exploring again (runs it lacks are explored, into `--keep` if given):
the run file is replayed through the pipeline's Mapper
as explore() fed it (the same maps, checked against the CSV's explored volume), the summary
comes from the run and the CSV (wall_s: null, unknown), and the timing probe runs at the CSV's
planning moments, from the pose the planner planned from (explore's estimate: the last scan's
navigation corrected by the last finished submap) on the map it had then. (A live probe runs
after the iteration's flight, on the map that flight extended, from the pose before it.)

Writes explore_<device>.json and explore_rmse.png, explore_timing.png, explore_volume.png.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import platform
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import warp as wp  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

import vogjax as vj  # noqa: E402
from vogjax import planner, scenes  # noqa: E402
from vogjax.config.planner import (
    PAPERS,  # noqa: E402
    PlannerConfig,  # noqa: E402
)
from vogjax.geometry import inverse  # noqa: E402
from vogjax.io.dataset import Dataset, ScanBatch  # noqa: E402
from vogjax.pipeline import Mapper  # noqa: E402
from vogjax.report.metrics import register_to_surface  # noqa: E402
from vogjax.sim import ranging, simulate_run  # noqa: E402
from vogjax.sim.explore import PIECE_SCANS, csv_path_of, explore, scene_planner  # noqa: E402

BOX_M = np.array(PlannerConfig().box_m)


SCAN_PERIOD_S = 0.2  # Table 4.2: the sonar's 5 frames per second


def table_4_2(seed: int) -> tuple[PlannerConfig, vj.PipelineConfig]:
    """Ho's propeller parameters (thesis Table 4.2): the planner's defaults with the papers' rule
    (`PAPERS`), OctoMap resolution 0.095 m, 100 scans per submap, and the thesis's drift (Eq. 4.1)."""
    # Eq. 4.1 adds dt * N(0, Sigma) to each step (Sigma in m^2/s, Sodhi's values): a variance of
    # dt * Sigma per second, a fifth of what Sodhi's Eq. 10 (NavNoise's reading) accrues at 5 Hz
    sodhi = vj.NavNoise()
    thesis = dataclasses.replace(
        sodhi,
        sigma2_x=sodhi.sigma2_x * SCAN_PERIOD_S,
        sigma2_y=sodhi.sigma2_y * SCAN_PERIOD_S,
        sigma2_yaw=sodhi.sigma2_yaw * SCAN_PERIOD_S,
    )
    return PlannerConfig(seed=seed, **PAPERS), vj.PipelineConfig(
        map=vj.MapConfig(voxel_size=0.095), scans_per_submap=100, nav_noise=thesis
    )


def occupied_centres(block_map) -> np.ndarray:
    centres, values = block_map.voxels()
    return centres[values >= block_map.config.log_occupied]


def reconstruction(points: np.ndarray, surface: np.ndarray, voxel_size: float) -> dict:
    """Table 4.3's RMSE (m) of a map's occupied voxel centres to the true surface after
    registration, and the share of the true surface within two voxels of a registered centre:
    a map whose drift erased surfaces keeps few voxels and can score a low RMSE on them."""
    if len(points) < 10:
        return {"rmse_m": float("nan"), "coverage": 0.0, "voxels": len(points)}
    T = register_to_surface(points, surface)
    moved = points @ T[:3, :3].T + T[:3, 3]
    distance, _ = cKDTree(surface).query(moved, workers=-1)
    reached, _ = cKDTree(moved).query(surface, distance_upper_bound=2 * voxel_size, workers=-1)
    return {
        "rmse_m": float(np.sqrt(np.mean(distance**2))),
        "coverage": float(np.isfinite(reached).mean()),
        "voxels": len(points),
    }


def box_hits(scene, truth: np.ndarray) -> int:
    """Scans whose collision box (around the true pose) holds a point of the true surface."""
    surface = scene.surface_points(400_000)
    lo, hi = surface.min(axis=0) - BOX_M, surface.max(axis=0) + BOX_M
    near = truth[np.all((truth[:, :3, 3] >= lo) & (truth[:, :3, 3] <= hi), axis=1)]
    return int(sum(np.any(np.all(np.abs(surface - p[:3, 3]) <= BOX_M / 2, axis=1)) for p in near))


def known_m3(vmap, lo, hi) -> float:
    """Known (free or occupied) volume of a map inside the box lo-hi (explore's explored_m3)."""
    centres, values = vmap.voxels()
    known = (values <= vmap.config.log_free) | (values >= vmap.config.log_occupied)
    inside = np.all((centres >= lo) & (centres <= hi), axis=1)
    return float(np.count_nonzero(known & inside) * vmap.config.voxel_size**3)


def explored_curve(path: Path, scene, voxel_size: float, every: int = 100) -> dict:
    """Known volume of the scene's region and of its exploration box in a map built from the
    run's true poses, every `every` scans, with mission time and true path length."""
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=voxel_size))
    region, bounds = scene.region(), scene.bounds
    out = {"scans": [], "time_s": [], "path_m": [], "region_m3": [], "bounds_m3": []}
    path_m, last = 0.0, None
    with Dataset(path) as run:
        for batch in run.batches(every):
            vmap.integrate_scans(*batch.beams(batch.pose_truth, vmap.config.max_range))
            positions = batch.pose_truth[:, :3, 3] if last is None else np.vstack([last, batch.pose_truth[:, :3, 3]])
            path_m += float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
            last = batch.pose_truth[-1, :3, 3]
            centres, values = vmap.voxels()
            known = (values <= vmap.config.log_free) | (values >= vmap.config.log_occupied)
            for key, (lo, hi) in (("region_m3", region), ("bounds_m3", bounds)):
                inside = np.all((centres >= lo) & (centres <= hi), axis=1)
                out[key].append(float(np.count_nonzero(known & inside) * voxel_size**3))
            out["scans"].append(batch.first + len(batch))
            out["time_s"].append(float(batch.time_s[-1]))
            out["path_m"].append(path_m)
    return out


class TimingProbe:
    """on_iteration hook: every `every` submaps, plan on the global and the virtual map side by
    side and time a fixed batch of gain views on each."""

    def __init__(self, config: PlannerConfig, scene, sensor, every: int, views: int = 200):
        self.config, self.scene, self.sensor, self.every, self.views = config, scene, sensor, every, views
        self.rows = []
        self.next = every

    def __call__(self, mapper, plan, row) -> None:
        self.measure(mapper, vj.geometry.pose_from_xyz_yaw(*plan.tree_states[0]))  # where it planned from

    def measure(self, mapper, T) -> None:
        if mapper.num_submaps < self.next:
            return
        self.next = mapper.num_submaps + self.every
        filling = list(range(mapper.num_submaps, len(mapper.submaps)))
        maps = {
            "global": planner.Overlay(mapper.global_map, mapper.vog, filling) if filling else mapper.global_map,
            "virtual": mapper.vog,
        }
        rng = np.random.default_rng(mapper.num_submaps)
        lo, hi = self.scene.bounds[0] + BOX_M / 2, self.scene.bounds[1] - BOX_M / 2
        views = (
            np.array(
                [
                    vj.geometry.pose_from_xyz_yaw(*rng.uniform(lo, hi), rng.uniform(-np.pi, np.pi))
                    for _ in range(self.views)
                ]
            )
            @ self.sensor.T_vehicle_sensor
        )
        entry = {"submaps": mapper.num_submaps}
        for name, m in maps.items():
            nbv = planner.NbvPlanner(
                self.config, bounds=self.scene.bounds, sensor=self.sensor, region=self.scene.region()
            )
            result = nbv.plan(m, T)
            per_ray = []
            for _ in range(3):
                start = time.perf_counter()
                gain = planner.view_gain(
                    m, views, self.sensor, max_range_m=self.config.gain_range_m, region=self.scene.region()
                )
                per_ray.append((time.perf_counter() - start) / gain.rays)
            entry[name] = {
                "plan_s": result.seconds,
                "plan_rays": result.rays,
                "nodes": result.nodes,
                "ray_s": float(np.median(per_ray)),
                "gain_rays": gain.rays,
            }
        print(
            f"  timing at {entry['submaps']} submaps: plan {entry['global']['plan_s']:.2f} s global, "
            f"{entry['virtual']['plan_s']:.2f} s virtual",
            flush=True,
        )
        self.rows.append(entry)


def replay(out: Path, rows, arm: str, seed: int, scene, probe=None) -> tuple[Mapper, dict]:
    """Feed a run file to the pipeline's Mapper as explore() fed it: from each planning moment
    (a CSV row's scan count) the flight's scans in pieces of PIECE_SCANS; at each planning
    moment the probe measures from explore's estimate. Returns the mapper and the summary
    explore() gave, rebuilt from the run and the CSV."""
    config, pipeline = table_4_2(seed)
    with Dataset(out) as run:
        expected = {
            "map": arm,
            "seed": seed,
            "planner": config.to_dict(),
            "nav_noise": pipeline.nav_noise.to_dict(),
            "pipeline": {"scans_per_submap": pipeline.scans_per_submap, "voxel_size": pipeline.map.voxel_size},
        }
        wrong = [key for key, value in expected.items() if run.metadata.get(key) != value]
        if wrong:
            raise ValueError(f"{out} was not explored with table_4_2's settings ({', '.join(wrong)} differ)")
        scans, sensor = run.read(0, len(run)), vj.sensors.from_metadata(run.metadata)
        mapper = Mapper(pipeline, run.metadata)
    moments = [int(r["scans"]) for r in rows]
    for start, end in zip([0] + moments, moments + [len(scans)]):
        if probe is not None and start and mapper.num_submaps >= probe.next:
            k = mapper.num_submaps - 1  # explore's estimate: navigation corrected by the last finished submap
            probe.measure(
                mapper, mapper.vog.pose(k) @ inverse(mapper.submaps[k].T_world_base_nav) @ scans.pose_nav[start - 1]
            )
        if start == moments[-1]:  # the last plan: the online global map's explored volume then
            explored = known_m3(mapper.global_map, *scene.region())
        for first in range(start, end, PIECE_SCANS):
            mapper.add(scans.rows(first, min(first + PIECE_SCANS, end)))
    mapper.finish_submap()
    last = rows[-1]
    positions = np.vstack([scene.start_pose[:3, 3], scans.pose_truth[:, :3, 3]])
    summary = {
        "scans": len(scans),
        "submaps": mapper.num_submaps,
        "iterations": len(rows),
        "stopped": ("gain" if last["nodes"] else "blocked") if np.isnan(last["x_m"]) else "submaps",
        "path_m": float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()),
        "duration_s": len(scans) / sensor.rate_hz,
        "wall_s": None,
        "reuse_check": {"explored_m3_csv": float(last["explored_m3"]), "explored_m3_replay": explored},
    }
    if not np.isclose(explored, last["explored_m3"], rtol=1e-5):
        print(
            f"  WARNING: the replay's explored volume at the last plan ({explored:.3f} m^3) is not the CSV's "
            f"({last['explored_m3']:.3f} m^3): the maps differ from the online ones",
            flush=True,
        )
    return mapper, summary


def run_arm(arm: str, seed: int, submaps: int, folder: Path, scene_name: str, probe=None, reuse=False) -> dict:
    out = folder / f"{arm}_{seed}.h5"
    scene = scenes.load(scene_name)
    if reuse:
        rows = list(np.genfromtxt(csv_path_of(out), delimiter=",", names=True))
        mapper, facts = replay(out, rows, arm, seed, scene, probe)
    else:
        config, pipeline = table_4_2(seed)
        kept = {}

        def hook(mapper, plan, row):
            kept["mapper"] = mapper
            if probe is not None:
                probe(mapper, plan, row)

        start = time.perf_counter()
        summary = explore(
            scene_name,
            out,
            submaps,
            map_kind=arm,
            seed=seed,
            planner_config=config,
            pipeline_config=pipeline,
            on_iteration=hook,
            overwrite=True,
        )
        seconds = time.perf_counter() - start
        mapper, rows = kept["mapper"], list(np.genfromtxt(summary.csv_path, delimiter=",", names=True))
        facts = {
            "scans": summary.scans,
            "submaps": summary.submaps,
            "iterations": summary.iterations,
            "stopped": summary.stopped,
            "path_m": summary.path_m,
            "duration_s": summary.duration_s,
            "wall_s": seconds,
        }
    result = mapper.result()
    surface = scene.surface_points(50_000)
    occupied = {
        key: occupied_centres(m)
        for key, m in (
            ("standard", result.standard_map),
            ("without_loop_closures", result.navigation_merge),
            ("with_loop_closures", result.global_map),
        )
    }
    with Dataset(out) as run:
        truth = run.read(0, len(run)).pose_truth
    plan_s = np.array([r["plan_s"] for r in rows])
    scores = {key: reconstruction(points, surface, 0.095) for key, points in occupied.items()}
    return {
        "arm": arm,
        "seed": seed,
        "reused": reuse,
        **facts,
        "rmse_m": {key: score["rmse_m"] for key, score in scores.items()},
        "coverage": {key: score["coverage"] for key, score in scores.items()},
        "occupied_voxels": {key: score["voxels"] for key, score in scores.items()},
        "trajectory_rmse_m": result.metrics["trajectory_rmse_m"],
        "loop_closures": result.metrics["loop_closures"]["accepted"],
        "collisions": box_hits(scene, truth),
        "plan_s_median": float(np.median(plan_s)),
        "plan_s_p90": float(np.percentile(plan_s, 90)),
        "rays_median": float(np.median([r["rays"] for r in rows])),
        "csv": {
            name: [float(r[name]) for r in rows]
            for name in ("time_s", "submaps", "explored_m3", "path_m", "plan_s", "rays")
        },
        "explored": explored_curve(out, scene, 0.095),
    }


def table_4_3(runs: list[dict]) -> list[dict]:
    """Per seed, as the thesis pairs them: the standard map of the standard arm's run; the maps
    without and with loop closures of the global arm's run; whether RMSE orders them as the
    thesis does (with LC < without LC < standard)."""
    rows = []
    for seed in sorted({r["seed"] for r in runs}):
        arm = {r["arm"]: r for r in runs if r["seed"] == seed}
        if {"standard", "global"} <= arm.keys():
            row = {
                "seed": seed,
                "standard": arm["standard"]["rmse_m"]["standard"],
                "without_loop_closures": arm["global"]["rmse_m"]["without_loop_closures"],
                "with_loop_closures": arm["global"]["rmse_m"]["with_loop_closures"],
            }
            row["ordered"] = bool(row["with_loop_closures"] < row["without_loop_closures"] < row["standard"])
            rows.append(row)
    return rows


# ------------------------------------------------------------------ planner vs scripted survey
TURN_IN_PLACE_SPEED_MPS = 0.05  # a fifth of the speed limit: the vehicle is not translating
TURNING_RATE_RPS = 0.03  # a fifth of the yaw-rate limit: the vehicle is turning
MEASURE_VOXEL_M = 0.1


def motion_shares(truth: np.ndarray, rate_hz: float) -> dict:
    """Shares of the scan intervals of a true path (S,4,4) spent turning (yaw rate above
    TURNING_RATE_RPS) and turning in place (that, translating slower than
    TURN_IN_PLACE_SPEED_MPS), with the yaw and path totals."""
    yaw = np.unwrap(np.arctan2(truth[:, 1, 0], truth[:, 0, 0]))
    rate = np.abs(np.diff(yaw)) * rate_hz
    speed = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1) * rate_hz
    turning = rate > TURNING_RATE_RPS
    return {
        "turning": float(turning.mean()) if len(rate) else 0.0,
        "turning_in_place": float((turning & (speed < TURN_IN_PLACE_SPEED_MPS)).mean()) if len(rate) else 0.0,
        "yaw_rad": float(np.abs(np.diff(yaw)).sum()),
        "path_m": float(speed.sum() / rate_hz),
    }


def volume_curve(path: Path, scene, every: int = 50, last: int | None = None) -> dict:
    """Known (free or occupied) volume of the scene's region in a 0.1 m map built from the
    run's beams at their true poses, after every `every` scans (and at the last, or at `last`)."""
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=MEASURE_VOXEL_M))
    lo, hi = scene.region()
    out = {"scans": [], "m3": []}
    with Dataset(path) as run:
        end = len(run) if last is None else min(last, len(run))
        for first in range(0, end, every):
            batch = run.read(first, min(first + every, end))
            vmap.integrate_scans(*batch.beams(batch.pose_truth, vmap.config.max_range))
            out["scans"].append(first + len(batch))
            out["m3"].append(known_m3(vmap, lo, hi))
    return out


def observable_m3(scene, spacing_m: float = 0.5, depths: int = 5, headings: int = 48) -> float:
    """An upper bound of what any exploration can know of the scene's region: the known volume
    (the measure of `volume_curve`) after noiseless scans from every pose of a grid over the
    sampling box (the bounds shrunk by half the default collision box; `spacing_m` apart in x-y,
    `depths` levels, `headings` headings each; for the tank only inside its wall), with no
    dynamics and no collision check, so it bounds every planner and survey alike."""
    half = np.array(PlannerConfig().box_m) / 2
    lo, hi = scene.bounds[0] + half, scene.bounds[1] - half
    xs, ys = (np.arange(lo[k], hi[k] + 1e-9, spacing_m) for k in (0, 1))
    x, y, z, yaw = np.meshgrid(
        xs, ys, np.linspace(lo[2], hi[2], depths), np.linspace(-np.pi, np.pi, headings, endpoint=False), indexing="ij"
    )
    states = np.c_[x.ravel(), y.ravel(), z.ravel(), yaw.ravel()]
    if scene.name == "tank":  # the vehicle's box inside the 3.5 m wall
        states = states[np.hypot(states[:, 0], states[:, 1]) <= 3.5 - np.hypot(*half[:2])]
    poses = np.array([vj.geometry.pose_from_xyz_yaw(*state) for state in states])
    sensor = vj.sensors.ProfilingSonar(vj.SonarConfig(range_noise_m=0.0))
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=MEASURE_VOXEL_M))
    for first in range(0, len(poses), 2000):
        T = poses[first : first + 2000]
        scans = ranging.scan(scene.warp_mesh, T @ sensor.T_vehicle_sensor, sensor, np.random.default_rng(0))
        fields = sensor.dataset_fields(scans.ranges, scans.no_return, scans.invalid)
        batch = ScanBatch(first, np.arange(len(T), dtype=np.float64), T, T, **fields)
        vmap.integrate_scans(*batch.beams(T, sensor.config.max_range_m))
    return known_m3(vmap, *scene.region())


@wp.kernel
def distance_to_surface(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), distance: wp.array(dtype=float)):
    tid = wp.tid()
    query = wp.mesh_query_point_no_sign(mesh, points[tid], 1.0e6)
    distance[tid] = 1.0e6
    if query.result:
        distance[tid] = wp.length(points[tid] - wp.mesh_eval_position(mesh, query.face, query.u, query.v))


def hidden_centres(scene, truth, depth_m: float) -> np.ndarray:
    """Centres of ground-truth voxels inside a solid (INSIDE) deeper than depth_m below its
    surface (tests/test_blind_distance.py holds the same reference)."""
    centres = truth.centres(scenes.INSIDE)
    if not len(centres):
        return centres
    distance = wp.empty(len(centres), dtype=float, device="cpu")
    wp.launch(
        distance_to_surface,
        dim=len(centres),
        inputs=[scene.warp_mesh.id, wp.array(centres, dtype=wp.vec3, device="cpu")],
        outputs=[distance],
        device="cpu",
    )
    return centres[distance.numpy() > depth_m]


def free_behind(scene, maps: dict, truth) -> dict:
    """FREE voxels behind a surface per map (wholly inside a solid; for the tank also outside its
    wall below its rim): maps on the world grid read at INSIDE centres deeper than half a
    voxel's diagonal, maps of submaps deeper than a whole diagonal (their voxels are pulled
    from the submaps' own grids)."""
    diagonal = np.sqrt(3) * truth.voxel_size
    # and three sigmas of the runs' 2 cm range noise: a return that far beyond the surface is
    # the sensor's, and the voxels before it are cleared
    noise = 0.06
    hidden = {reach: hidden_centres(scene, truth, reach + noise) for reach in (diagonal / 2, diagonal)}
    out = {}
    for name, m in maps.items():
        reach = diagonal / 2 if name in ("standard", "true_pose_map") else diagonal
        count = int(np.count_nonzero(m.state(hidden[reach]) == vj.FREE)) if len(hidden[reach]) else 0
        if scene.name == "tank" and hasattr(m, "voxels"):
            centres = m.voxels()[0]
            free = centres[m.state(centres) == vj.FREE]
            radius = np.linalg.norm(free[:, :2], axis=1)
            count += int(np.count_nonzero((radius > 3.7 + reach + noise) & (free[:, 2] < 3.1 - reach)))
        out[name] = count
    return out


def compare_run(scene_name: str, seed: int, submaps: int, folder: Path, config: PlannerConfig, label: str) -> dict:
    """One `explore` run (`config`; the pipeline's defaults) of `submaps` submaps, measured: its
    volume curve from true poses, collisions of the true box with the true mesh, motion, planning
    times, predicted and realised gain (its CSV), free voxels behind surfaces in every map."""
    scene = scenes.load(scene_name)
    out = folder / f"{scene_name}_{label}_{seed}.h5"
    kept = {}
    start = time.perf_counter()
    summary = explore(
        scene_name,
        out,
        submaps,
        seed=seed,
        planner_config=config,
        on_iteration=lambda mapper, plan, row: kept.update(mapper=mapper),
        overwrite=True,
        progress=False,
    )
    wall_s = time.perf_counter() - start
    with open(summary.csv_path) as f:
        rows = list(csv.DictReader(f))
    with Dataset(out) as run:
        truth_poses = run.read(0, len(run)).pose_truth
        rate_hz = vj.sensors.from_metadata(run.metadata).rate_hz
    result = kept["mapper"].result()
    true_map = vj.VoxelMap(vj.MapConfig(voxel_size=MEASURE_VOXEL_M))
    with Dataset(out) as run:
        for batch in run.batches(500):
            true_map.integrate_scans(*batch.beams(batch.pose_truth, 11.0))
    behind = free_behind(
        scene,
        {
            "true_pose_map": true_map,
            "truth_merge": result.truth_merge,
            "standard": result.standard_map,
            "global": result.global_map,
        },
        scene.occupancy(MEASURE_VOXEL_M),
    )
    names = list(rows[0]) if rows else []
    column = lambda name: np.array([float(r[name]) for r in rows]) if name in names else np.zeros(0)  # noqa: E731
    return {
        "scene": scene_name,
        "seed": seed,
        "rule": label,
        "scans": summary.scans,
        "submaps": summary.submaps,
        "iterations": summary.iterations,
        "stopped": summary.stopped,
        "wall_s": wall_s,
        "volume": volume_curve(out, scene),
        "motion": motion_shares(truth_poses, rate_hz),
        "collisions": box_hits(scene, truth_poses),
        "free_behind_surfaces": behind,
        "plan_s": column("plan_s").tolist(),
        "predicted_m3": column("predicted_m3").tolist(),
        "realised_m3": column("realised_m3").tolist(),
        "step": [str(r["step"]) for r in rows] if "step" in names else [],
        "run": str(out),
    }


def machine() -> dict:
    """Where it ran: CPU, cores, load when it started, Python, device."""
    import os

    return {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "load_1min_at_start": os.getloadavg()[0],
        "python": platform.python_version(),
        "device": str(vj.devices.resolve(None)),
        "date": time.strftime("%Y-%m-%d"),
    }


def plot_compare(report: dict, path: Path) -> None:
    """Known volume over scans, planner (one line per seed) against the scripted survey, per scene."""
    names = list(dict.fromkeys(r["scene"] for r in report["runs"]))
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names):
        runs = [r for r in report["runs"] if r["scene"] == name]
        longest = max(runs, key=lambda r: r["scans"])
        ax.plot(longest["survey_curve"]["scans"], longest["survey_curve"]["m3"], "k-", lw=2, label="scripted survey")
        for r in runs:
            label = f"planner, seed {r['seed']} ({r['ratio']:.2f}x)"
            ax.plot(r["volume"]["scans"], r["volume"]["m3"], "-", label=label)
        ax.set_title(f"{name}")
        ax.set_xlabel("scans")
        ax.set_ylabel("known volume of the scene [m^3]")
        ax.legend(fontsize=7)
    fig.suptitle(
        f"Exploration ({report['rule']} rule) vs the scripted survey at equal scans, {report['submaps']} submaps"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def settings(pairs: list[str]) -> dict:
    """PlannerConfig changes from KEY=VALUE strings (TOML values: 1.5, true, "frontier")."""
    import tomllib

    return {key: value for pair in pairs for key, value in tomllib.loads(pair).items()}


def compare_scenes(args) -> dict:
    """Per scene and seed: the planner (time-aware rule, or `--rule papers`) against the
    scripted survey of `vogjax simulate` at the planner's scan count."""
    folder = args.keep or Path(tempfile.mkdtemp())
    folder.mkdir(parents=True, exist_ok=True)
    runs, surveys = [], {}
    for scene_name in args.scenes.split(","):
        for seed in [int(x) for x in args.seeds.split(",")]:
            config = scene_planner(scene_name, seed, args.rule).replace(**settings(args.set))
            r = compare_run(scene_name, seed, args.submaps, folder, config, args.label or args.rule)
            if scene_name not in surveys:
                survey_path = folder / f"{scene_name}_survey.h5"
                if survey_path.exists():  # kept from an earlier comparison: the same survey
                    with Dataset(survey_path) as ds:
                        if len(ds) >= r["scans"]:
                            surveys[scene_name] = survey_path
            if scene_name not in surveys:
                simulate_run(
                    scene_name,
                    survey_path,
                    num_scans=max(3 * r["scans"], 2000),
                    sensor=vj.sensors.ProfilingSonar(vj.SonarConfig(range_noise_m=0.02)),
                    progress=False,
                    overwrite=True,
                )
                surveys[scene_name] = survey_path
            scene = scenes.load(scene_name)
            equal = volume_curve(surveys[scene_name], scene, every=50, last=r["scans"])
            r["survey_m3_at_equal_scans"] = equal["m3"][-1]
            r["survey_curve"] = equal
            r["planner_m3"] = r["volume"]["m3"][-1]
            r["ratio"] = r["planner_m3"] / r["survey_m3_at_equal_scans"]
            runs.append(r)
            print(
                f"{scene_name} seed {seed} [{args.rule}]: {r['scans']} scans, {r['planner_m3']:.1f} m^3 vs survey "
                f"{r['survey_m3_at_equal_scans']:.1f} m^3 = {r['ratio']:.2f}x; turning in place "
                f"{r['motion']['turning_in_place']:.0%} (turning {r['motion']['turning']:.0%}); collisions "
                f"{r['collisions']}; behind surfaces {r['free_behind_surfaces']}; plan median "
                f"{np.median(r['plan_s']):.3f} s; predicted/realised "
                f"{np.sum(r['predicted_m3']):.0f}/{np.sum(r['realised_m3']):.0f} m^3",
                flush=True,
            )
    observable = {}
    for scene_name in surveys:
        observable[scene_name] = observable_m3(scenes.load(scene_name))
        print(
            f"{scene_name}: observable from the sampling box (upper bound) {observable[scene_name]:.1f} m^3", flush=True
        )
    return {"runs": runs, "surveys": {k: str(v) for k, v in surveys.items()}, "observable_m3": observable}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--scene", default="propeller")
    parser.add_argument(
        "--submaps", type=int, default=None, help="submaps per run (default: Table 4.2's 156; with --compare 12)"
    )
    parser.add_argument(
        "--compare",
        action="store_true",
        help="planner vs scripted survey per scene and seed (--scenes, --seeds, --rule) instead of the papers' figures",
    )
    parser.add_argument("--scenes", default="propeller,pilings,tank,boxes", help="with --compare: scenes")
    parser.add_argument("--seeds", default="3,4,5", help="with --compare: seeds")
    parser.add_argument("--rule", default="time", choices=("time", "papers"), help="with --compare: planner rule")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        help='with --compare: a PlannerConfig change, KEY=VALUE (TOML: gain="frontier")',
    )
    parser.add_argument(
        "--label", default=None, help="with --compare: the name of the runs and outputs (default: the rule)"
    )
    parser.add_argument("--runs", type=int, default=2, help="runs per arm")
    parser.add_argument("--arms", default="standard,global", help="maps the planner plans on")
    parser.add_argument("--timing-every", type=int, default=15, help="submaps between timing probes (0: none)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the run files in this folder")
    parser.add_argument(
        "--reuse",
        type=Path,
        default=None,
        help="take ARM_SEED.h5 and ARM_SEED.explore.csv from this folder where there (no exploring)",
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    device = vj.devices.resolve(None)
    if args.compare:
        args.submaps = args.submaps or 12
        report = {
            "machine": machine(),
            "submaps": args.submaps,
            "rule": args.rule,
            **compare_scenes(args),
        }
        label = args.label or args.rule
        report["settings"] = settings(args.set)
        path = args.out / f"explore_compare_{label}_{'cuda' if device.is_cuda else 'cpu'}.json"
        path.write_text(json.dumps(report, indent=1))
        plot_compare(report, args.out / f"explore_compare_{label}.png")
        print(f"wrote {path}")
        return
    args.submaps = args.submaps or 156
    scene = scenes.load(args.scene)
    sonar = vj.sensors.ProfilingSonar(vj.SonarConfig(range_noise_m=0.02))
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.keep or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        runs, probe = [], None
        for seed in range(args.runs):
            for arm in args.arms.split(","):
                probe_here = None
                if arm == "global" and seed == 0 and args.timing_every > 0:
                    probe = probe_here = TimingProbe(table_4_2(0)[0], scene, sonar, args.timing_every)
                reuse = (
                    args.reuse is not None
                    and (args.reuse / f"{arm}_{seed}.h5").exists()
                    and csv_path_of(args.reuse / f"{arm}_{seed}.h5").exists()
                )
                print(f"{'replaying' if reuse else 'exploring'}: {arm} map, seed {seed}", flush=True)
                runs.append(
                    run_arm(arm, seed, args.submaps, args.reuse if reuse else folder, args.scene, probe_here, reuse)
                )
                r = runs[-1]
                print(
                    f"  {r['scans']} scans, {r['submaps']} submaps, stopped: {r['stopped']}, RMSE {r['rmse_m']}, "
                    f"collisions {r['collisions']}, plan {r['plan_s_median']:.2f} s median",
                    flush=True,
                )
        scans = max(r["scans"] for r in runs)
        survey_path = folder / "survey.h5"
        simulate_run(args.scene, survey_path, num_scans=scans, sensor=sonar, progress=False)
        survey = explored_curve(survey_path, scene, 0.095)
    report = {
        "machine": {"cpu": platform.machine(), "python": platform.python_version(), "device": str(device)},
        "scene": args.scene,
        "submaps": args.submaps,
        "runs": runs,
        "survey": survey,
        "table_4_3": table_4_3(runs),
        "timing": probe.rows if probe else [],
        "planner": table_4_2(0)[0].to_dict(),
    }
    for row in report["table_4_3"]:
        print(
            f"Table 4.3, seed {row['seed']}: standard {row['standard']:.3f} m, without LC "
            f"{row['without_loop_closures']:.3f} m, with LC {row['with_loop_closures']:.3f} m, "
            f"{'ordered as the thesis' if row['ordered'] else 'NOT ordered as the thesis'}"
        )
    path = args.out / f"explore_{'cuda' if device.is_cuda else 'cpu'}.json"
    path.write_text(json.dumps(report, indent=1))
    plot(report, args.out)
    print(f"wrote {path}")


def plot(report: dict, folder: Path) -> None:
    runs = report["runs"]
    # 1. RMSE per run: the standard arm's standard map, the global arm's maps without and with LC
    labels, values, colours = [], [], []
    colour_of = {"standard": "tab:red", "without_loop_closures": "tab:orange", "with_loop_closures": "tab:blue"}
    short = {"standard": "standard", "without_loop_closures": "without LC", "with_loop_closures": "with LC"}
    for r in runs:
        keys = ("standard",) if r["arm"] == "standard" else ("without_loop_closures", "with_loop_closures")
        for key in keys:
            labels.append(f"run {r['seed'] + 1}\n{short[key]}\n{r['coverage'][key]:.0%} of\nsurface")
            values.append(r["rmse_m"][key])
            colours.append(colour_of[key])
    fig, ax = plt.subplots(figsize=(max(6.0, 0.75 * len(values)), 3.8))
    ax.bar(range(len(values)), values, color=colours)
    ax.set_xticks(range(len(values)), labels, fontsize=7)
    ax.set_yscale("log")  # a map without loop closures can be metres off
    ax.set_ylabel("reconstruction RMSE [m]")
    ax.set_title(
        "Propeller explored by the planner (Ho Table 4.3): red standard map (planner on it),\n"
        "orange / blue the global-map run's virtual map without / with loop closures",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(folder / "explore_rmse.png", dpi=120)
    plt.close(fig)
    # 2. timing against submaps, global vs virtual (Sodhi Fig. 8, with the planner's queries)
    if report["timing"]:
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
        n = [t["submaps"] for t in report["timing"]]
        for name, colour in (("global", "tab:blue"), ("virtual", "tab:orange")):
            axes[0].plot(n, [t[name]["ray_s"] * 1e6 for t in report["timing"]], "o-", color=colour, label=name)
            axes[1].plot(n, [t[name]["plan_s"] for t in report["timing"]], "o-", color=colour, label=name)
        axes[0].set_ylabel("median time per gain ray [us]")
        axes[1].set_ylabel("planning iteration [s]")
        for ax in axes:
            ax.set_xlabel("submaps")
            ax.legend()
        fig.suptitle(f"Planner queries, global vs virtual map ({report['machine']['device']})")
        fig.tight_layout()
        fig.savefig(folder / "explore_timing.png", dpi=120)
        plt.close(fig)
    # 3. explored volume against time and against path length: the scene's region, and the
    # exploration bounds the planner flies in
    fig, axes = plt.subplots(2, 2, figsize=(9, 7))
    volumes = (
        ("region_m3", "explored volume of the scene [m^3]"),
        ("bounds_m3", "explored volume inside the bounds [m^3]"),
    )
    for row, (key, label) in zip(axes, volumes):
        for r in runs:
            e = r["explored"]
            style = "-" if r["arm"] == "global" else "--"
            for ax, x in zip(row, ("time_s", "path_m")):
                ax.plot(e[x], e[key], style, label=f"planner, {r['arm']} map, seed {r['seed']}")
        for ax, x in zip(row, ("time_s", "path_m")):
            ax.plot(report["survey"][x], report["survey"][key], "k-", lw=2, label="scripted survey")
            ax.set_xlabel({"time_s": "mission time [s]", "path_m": "path length [m]"}[x])
            ax.set_ylabel(label)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder / "explore_volume.png", dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
