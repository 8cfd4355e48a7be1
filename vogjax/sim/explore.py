"""Closed-loop exploration: the planner picks where the vehicle goes while SLAM maps under it.

    summary = explore("propeller", "run.h5", submaps=150)   # and run.explore.csv beside it

Per planning iteration (Ho, thesis 4.3-4.5; Sodhi IV): the vehicle's estimated pose is its
navigation corrected by the pose graph (the last finished submap's correction), the
next-best-view planner plans on the chosen map from it, and the vehicle flies the best branch's
first edge: MJX physics under the waypoint controller, the sonar scanning the true scene at
5 Hz, navigation drifting. Scans go to the mapper (submaps, loop closures, the online global
map) as they arrive and to the run file. A waypoint planned in the estimated frame is flown as
the motion it asks for relative to where the vehicle believes it is (as a controller on the
navigation would fly it), so drift carries into the true path.

Maps the planner can use: "global", the online global map (with the submap being filled laid
over it, `planner.Overlay`); "virtual", the virtual map (the sum over submaps); "standard",
the navigation-only map, planned from the navigation pose (the papers' baseline).
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
from tqdm import tqdm

import vogjax
from vogjax import scenes
from vogjax.config import ControllerConfig, NavNoise, PipelineConfig, SonarConfig
from vogjax.config.planner import PAPERS, ExploreConfig, PlannerConfig
from vogjax.config.schema import read_toml
from vogjax.geometry import inverse, pose_from_xyz_yaw, yaw_pitch_roll
from vogjax.io.atomic import AtomicPath, check_writable
from vogjax.io.dataset import DatasetWriter, ScanBatch
from vogjax.maps import VogMap
from vogjax.pipeline import Mapper
from vogjax.planner import NbvPlanner, Overlay
from vogjax.sensors import ProfilingSonar, RangeSensor, as_sensor
from vogjax.sim import ranging, vehicle
from vogjax.sim.stepped_navigation import SteppedNavigation

MAPS = ("global", "virtual", "standard")
# Scans flown per compiled MJX call; a flight is cut where the waypoint is reached.
PIECE_SCANS = 10
CSV_FIELDS = (
    "iteration",
    "time_s",
    "scans",
    "submaps",
    "explored_m3",
    "path_m",
    "plan_s",
    "rays",
    "gain_m3",
    "nodes",
    "samples",
    "x_m",
    "y_m",
    "z_m",
    "yaw_rad",
    "reached",
    "score",
    "branch_s",
    "predicted_m3",
    "realised_m3",
    "step",
)


@dataclasses.dataclass(frozen=True)
class ExploreSummary:
    """path, csv_path: the files written; scans, submaps (finished), iterations (plans);
    duration_s of the mission; path_m flown (true path); explored_m3: known volume of the
    scene's region in the final global map; stopped: "submaps" (reached the number asked for),
    "gain" (the best branch gained no more than min_gain_m3), "blocked" (no collision-free edge)
    or "scans" (max_scans reached)."""

    path: Path
    csv_path: Path
    scans: int
    submaps: int
    iterations: int
    duration_s: float
    path_m: float
    explored_m3: float
    stopped: str


# The papers' planner settings per scene: Ho's tank (thesis Table 4.4: 1 m edges, the sensor's
# 5.63 m range, no discount); every other scene takes Table 4.2's (PlannerConfig's defaults).
SCENE_PLANNERS = {"tank": {"edge_length_m": 1.0, "gain_range_m": 5.63, "discount": 0.0}}
RULES = ("time", "papers")


def scene_planner(scene_name: str, seed: int = 0, rule: str = "time") -> PlannerConfig:
    """The planner settings for a scene, seeded with `seed`.

    Parameters
    ----------
    scene_name : str
        A built-in scene.
    seed : int
        The sampling's seed.
    rule : {"time", "papers"}
        "time": PlannerConfig's defaults (the time-aware rule); "papers": the papers' rule
        (`vogjax.config.planner.PAPERS`) with the papers' settings for the scene (thesis
        Table 4.4 for the tank, Table 4.2 for the others).

    Returns
    -------
    PlannerConfig
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(RULES)}, got {rule!r}")
    if rule == "papers":
        return PlannerConfig(seed=seed, **{**PAPERS, **SCENE_PLANNERS.get(scene_name, {})})
    return PlannerConfig(seed=seed)


def load_settings(path, scene_name: str, seed: int | None, rule: str = "time") -> tuple[PlannerConfig, PipelineConfig]:
    """The planner's and the pipeline's settings: the scene's for `rule` (`scene_planner`) and
    PipelineConfig's defaults, under what a TOML file (None: none) sets; the planner seeded
    with `seed` (``--seed``, which wins over the file), or when None with the file's
    ``[planner] seed``, else 0. The planner's seed is the run's: it seeds the navigation and
    the range noise too.

    Raises
    ------
    ValueError
        Naming the file, if it is not a valid settings file.
    """
    document = read_toml(path) if path is not None else {}
    config = ExploreConfig.from_file_document(document, path) if path is not None else ExploreConfig()
    given = document.get("planner", {})
    changes = {key: getattr(config.planner, key) for key in given}  # checked by from_document
    if seed is None:
        seed = changes.get("seed", 0)
    return scene_planner(scene_name, seed, rule).replace(**{**changes, "seed": seed}), config.pipeline


def csv_path_of(out) -> Path:
    """RUN.explore.csv beside RUN.h5."""
    out = Path(out)
    return out.with_name(out.stem + ".explore.csv")


def explore(
    scene_name: str,
    out,
    submaps: int,
    map_kind: str = "global",
    seed: int = 0,
    planner_config: PlannerConfig | None = None,
    pipeline_config: PipelineConfig | None = None,
    sensor: RangeSensor | None = None,
    noise: NavNoise | None = None,
    max_scans: int | None = None,
    progress: bool = True,
    on_iteration=None,
    overwrite: bool = False,
) -> ExploreSummary:
    """Explore a built-in scene until `submaps` submaps are finished (or the gain runs out) and
    write the run to `out` (HDF5, a normal run `vogjax map` reprocesses) and one row per
    planning iteration to RUN.explore.csv. planner_config: default the time-aware rule's
    settings (`scene_planner`); sensor: default the papers' profiling sonar with 2 cm range noise;
    on_iteration(mapper, plan, row): called after each plan (benchmarks); overwrite: replace an
    existing `out` and its CSV (else that is an error, raised before any work)."""
    if map_kind not in MAPS:
        raise ValueError(f"map_kind must be one of {', '.join(MAPS)}, got {map_kind!r}")
    out = Path(out)
    for path in (out, csv_path_of(out)):
        if path.exists() and not overwrite:
            raise ValueError(f"out {str(path)!r} exists (pass overwrite=True, or --overwrite, to replace it)")
        check_writable(path)
    if not (isinstance(submaps, int) and submaps >= 1):
        raise ValueError(f"submaps must be a positive integer, got {submaps!r}")
    if max_scans is not None and not (isinstance(max_scans, int) and max_scans >= 1):
        raise ValueError(f"max_scans must be a positive integer, got {max_scans!r}")
    scene = scenes.load(scene_name)
    planner_config = planner_config or scene_planner(scene_name, seed)
    pipeline_config = pipeline_config or PipelineConfig()
    if map_kind == "standard" and not pipeline_config.standard_map:
        raise ValueError("map_kind 'standard' needs pipeline_config.standard_map")
    sensor = ProfilingSonar(SonarConfig(range_noise_m=0.02)) if sensor is None else as_sensor(sensor)
    vehicle.steps_per_scan(sensor.rate_hz, "sensor.rate_hz")  # scan times k / rate_hz as simulated
    noise = noise or pipeline_config.nav_noise
    metadata = {
        "scene": scene_name,
        "seed": seed,
        "mission": "explore",
        "map": map_kind,
        **sensor.metadata(),
        "nav_noise": noise.to_dict(),
        "planner": planner_config.to_dict(),
        "pipeline": {
            "scans_per_submap": pipeline_config.scans_per_submap,
            "voxel_size": pipeline_config.map.voxel_size,
        },
        "vogjax_version": vogjax.__version__,
    }
    # the vehicle flies an edge as the planner costs it: turning while it translates (or, for
    # the papers' rule, each axis at its own limit)
    controller = ControllerConfig(yaw_along_path=planner_config.yaw_along_path)
    loop = _Loop(scene, sensor, noise, seed, pipeline_config, metadata, controller)
    region = scene.bounds if planner_config.gain_region == "bounds" else scene.region()
    nbv = NbvPlanner(planner_config, bounds=scene.bounds, sensor=sensor, region=region)
    rows = []
    stopped = "submaps"
    with (
        DatasetWriter(out, sensor.beams, metadata) as writer,
        tqdm(total=submaps, unit="submap", desc=f"exploring {scene_name}", disable=not progress) as bar,
    ):
        loop.writer = writer
        # nbvplanner's initial motion: a turn in place, so the first tree has a map to grow in
        # (a full turn flown as four quarter turns; the default)
        x, y, z, yaw = loop.true_state()
        quarters = int(np.ceil(planner_config.initial_turn_rad / (np.pi / 2) - 1e-9))
        if quarters:
            step = planner_config.initial_turn_rad / quarters
            loop.fly([[x, y, z, yaw + step * k] for k in range(1, quarters + 1)])
        while loop.mapper.num_submaps < submaps:
            if max_scans is not None and loop.scans >= max_scans:
                stopped = "scans"
                break
            T_plan = loop.estimate(map_kind)
            planning_map = loop.planning_map(map_kind)
            plan = nbv.plan(planning_map, T_plan, drift_m=loop.drift_m(pipeline_config.nav_noise))
            seconds, step = plan.seconds, "local"
            spent = len(plan.waypoints) == 0 or plan.gain_m3 <= planner_config.min_gain_m3
            if planner_config.global_step and (spent or plan.score <= planner_config.global_below):
                # little left to see nearby: a trip over the explored graph, if one gains more
                trip = nbv.reposition(planning_map, T_plan)
                seconds += trip.seconds
                if len(trip.waypoints) and (spent or trip.score > plan.score):
                    plan, step, spent = trip, "global", False
            row = {
                "iteration": len(rows),
                "time_s": loop.scans / sensor.rate_hz,
                "scans": loop.scans,
                "submaps": loop.mapper.num_submaps,
                "explored_m3": loop.explored_m3(),
                "path_m": loop.path_m,
                "plan_s": seconds,
                "rays": plan.rays,
                "gain_m3": plan.gain_m3,
                "nodes": plan.nodes,
                "samples": plan.iterations,
                "score": plan.score,
                "branch_s": plan.branch_s,
                "predicted_m3": plan.first_edge_m3,
                "step": step,
            }
            if spent:
                flown = dict.fromkeys(("x_m", "y_m", "z_m", "yaw_rad", "realised_m3"), float("nan"))
                rows.append({**row, **flown, "reached": False})
                stopped = "gain" if plan.nodes else "blocked"
                if on_iteration:
                    on_iteration(loop.mapper, plan, rows[-1])
                break
            # the motion the plan asks for, relative to where the vehicle believed it was when it
            # planned: a local step flies the best branch's first edge, a global step its whole trip
            T_true_plan = loop.truth[-1] @ inverse(T_plan)
            known_m3 = loop.known_m3(nbv.region)
            for goal in plan.waypoints if step == "global" else plan.waypoints[:1]:
                T_goal = T_true_plan @ pose_from_xyz_yaw(*goal)
                target = np.r_[T_goal[:3, 3], yaw_pitch_roll(T_goal[:3, :3])[0]]
                reached = loop.fly([target], timeout_s=_timeout_s(loop.true_state(), target, controller))
                if step == "global":
                    if not reached:
                        break
                    nbv.arrived(goal)
            rows.append(
                {
                    **row,
                    "x_m": goal[0],
                    "y_m": goal[1],
                    "z_m": goal[2],
                    "yaw_rad": goal[3],
                    "reached": reached,
                    "realised_m3": loop.known_m3(nbv.region) - known_m3,
                }
            )
            if on_iteration:
                on_iteration(loop.mapper, plan, rows[-1])
            bar.update(loop.mapper.num_submaps - bar.n)
        loop.mapper.finish_submap()
        bar.update(loop.mapper.num_submaps - bar.n)  # the turn in place and the last submap count too
    _write_csv(csv_path_of(out), rows)
    return ExploreSummary(
        Path(out),
        csv_path_of(out),
        loop.scans,
        loop.mapper.num_submaps,
        len(rows),
        loop.scans / sensor.rate_hz,
        loop.path_m,
        loop.explored_m3(),
        stopped,
    )


def _timeout_s(state: np.ndarray, target: np.ndarray, config: ControllerConfig = ControllerConfig()) -> float:
    """Time to fly to the target at the speed limits, twice over, plus 10 s."""
    distance = np.linalg.norm(target[:3] - state[:3])
    turn = abs((target[3] - state[3] + np.pi) % (2 * np.pi) - np.pi)
    return 2.0 * (distance / config.max_speed_mps + turn / config.max_yaw_rate_rps) + 10.0


class _Loop:
    """The simulated vehicle and its mapper: flies, scans, drifts, maps, records."""

    def __init__(
        self,
        scene,
        sensor: RangeSensor,
        noise: NavNoise,
        seed: int,
        config: PipelineConfig,
        metadata: dict,
        controller: ControllerConfig = ControllerConfig(),
    ):
        self.scene, self.sensor, self.controller = scene, sensor, controller
        self.mapper = Mapper(config, metadata)
        self.navigation = SteppedNavigation(noise, seed)
        self.rng = np.random.default_rng(seed + 1)
        self.qpos, self.qvel = vehicle.resting_state(scene.start_pose)
        self.truth = [scene.start_pose]
        self.nav = [scene.start_pose]
        self.scans = 0
        self.path_m = 0.0
        self.writer = None
        self._batches: list[ScanBatch] = []  # the recent scans, from the first the mapper holds
        self._held, self._held_submaps, self._held_upto = None, -1, 0

    def true_state(self) -> np.ndarray:
        T = self.truth[-1]
        return np.r_[T[:3, 3], yaw_pitch_roll(T[:3, :3])[0]]

    def estimate(self, map_kind: str) -> np.ndarray:
        """The pose the planner plans from: navigation, corrected by the pose graph through the
        last finished submap (navigation alone for the standard map)."""
        return self.correction(map_kind) @ self.nav[-1]

    def correction(self, map_kind: str) -> np.ndarray:
        """(4,4) what takes a navigation pose into the planning frame: the last finished
        submap's correction by the pose graph (none for the standard map)."""
        k = self.mapper.num_submaps - 1
        if map_kind == "standard" or k < 0:
            return np.eye(4)
        return self.mapper.vog.pose(k) @ inverse(self.mapper.submaps[k].T_world_base_nav)

    def planning_map(self, map_kind: str):
        mapper = self.mapper
        if map_kind == "standard":
            return mapper.standard_map
        if map_kind == "virtual":
            return mapper.vog
        filling = list(range(mapper.num_submaps, len(mapper.submaps)))
        # the mapper holds the scans of the submap being filled until it is complete: without
        # them the planner would not see the last up to 100 scans, and would plan to look again
        # at what it has just seen
        return Overlay(mapper.global_map, mapper.vog, filling, extra=self.held_scans_map())

    def held_scans_map(self) -> VogMap:
        """The scans the mapper holds (not yet in any submap) as one submap of a VogMap, at the
        poses the planner estimates for them (their navigation with the last finished
        submap's correction, as `estimate`), in the planning frame. Kept up to date scan batch
        by scan batch; rebuilt when a submap is finished (the scans it took leave, and the
        correction changes)."""
        mapper = self.mapper
        first = mapper.submaps[-1].first_scan + mapper.submaps[-1].scans if mapper.submaps else 0
        if self._held is None or self._held_submaps != mapper.num_submaps:
            self._held = VogMap(mapper.config.map)
            self._held.add_submap(np.eye(4))
            self._held_submaps, self._held_upto = mapper.num_submaps, first
        self._batches = [b for b in self._batches if b.first + len(b) > first]
        correction = self.correction("global")
        for batch in self._batches:
            if batch.first + len(batch) <= self._held_upto:
                continue
            part = batch.rows(max(self._held_upto - batch.first, 0), len(batch))
            self._held.submap(0).integrate_scans(*part.beams(correction @ part.pose_nav, mapper.reach_m))
            self._held_upto = part.first + len(part)
        return self._held

    def explored_m3(self) -> float:
        """Known (free or occupied) volume of the scene's region in the global map."""
        gmap = self.mapper.global_map
        centres, values = gmap.voxels()
        lo, hi = self.scene.region()
        inside = np.all((centres >= lo) & (centres <= hi), axis=1)
        known = (values <= gmap.config.log_free) | (values >= gmap.config.log_occupied)
        return float(np.count_nonzero(inside & known) * gmap.config.voxel_size**3)

    def drift_m(self, noise: NavNoise) -> float:
        """How far (one sigma, per x-y axis, metres) the estimate may have drifted from the map:
        what `noise` accrues since the base scan of the latest submap a loop closure anchored
        (since the start, before any), the closures having tied the estimate to the map there."""
        anchored_s = 0.0
        if self.mapper.accepted:
            latest = max(max(c.i, c.k) for c in self.mapper.accepted)
            anchored_s = self.mapper.submaps[latest].time_s
        return float(
            np.sqrt(max(noise.sigma2_x, noise.sigma2_y) * max(self.scans / self.sensor.rate_hz - anchored_s, 0.0))
        )

    def known_m3(self, region) -> float:
        """Known volume inside `region` ((2,3), None: everywhere) of the map that follows the
        vehicle scan by scan: the navigation-only standard map (the global map takes a submap only
        once it is complete), else the global map. Drift moves that map's voxels, barely their
        number, so its change over a flight is the volume the flight revealed."""
        m = self.mapper.standard_map or self.mapper.global_map
        centres, values = m.voxels()
        known = (values <= m.config.log_free) | (values >= m.config.log_occupied)
        if region is not None:
            known &= np.all((centres >= region[0]) & (centres <= region[1]), axis=1)
        return float(np.count_nonzero(known) * m.config.voxel_size**3)

    def fly(self, waypoints, timeout_s: float | None = None) -> bool:
        """Fly through waypoints (W,4) in the true frame, scanning, until the last one is reached
        (or timeout_s passes); True when reached."""
        waypoints = np.asarray(waypoints, np.float64).reshape(-1, 4)
        rate = self.sensor.rate_hz
        limit = np.inf if timeout_s is None else timeout_s * rate
        flown = 0
        while flown < limit:
            flight = vehicle.fly(self.qpos, self.qvel, waypoints, PIECE_SCANS, rate, self.controller)
            done = (flight.index == len(waypoints) - 1) & _near(flight.poses, waypoints[-1], self.controller)
            keep = int(np.argmax(done)) + 1 if done.any() else PIECE_SCANS
            self._record(flight.poses[:keep])
            self.qpos, self.qvel = flight.qpos[keep - 1], flight.qvel[keep - 1]
            waypoints = waypoints[int(flight.index[keep - 1]) :]  # each piece starts at its first
            flown += keep
            if done.any():
                return True
        return False

    def _record(self, truth: np.ndarray) -> None:
        """Scan at the true poses, drift the navigation, map and record the scans."""
        rate = self.sensor.rate_hz
        times = (self.scans + np.arange(len(truth))) / rate
        nav = self.navigation.extend(truth, times)  # the run's first scan: the truth itself
        scans = ranging.scan(self.scene.warp_mesh, truth @ self.sensor.T_vehicle_sensor, self.sensor, self.rng)
        fields = self.sensor.dataset_fields(scans.ranges, scans.no_return, scans.invalid)
        # what the run file stores (float32 beams), so reprocessing it sees the same scans
        fields = {
            "sonar_origin": fields["sonar_origin"].astype(np.float32),
            "sonar_directions": fields["sonar_directions"].astype(np.float32),
            "ranges": fields["ranges"].astype(np.float32),
            "no_return": fields["no_return"],
            "invalid": fields["invalid"],
        }
        self.writer.append(time_s=times, pose_truth=truth, pose_nav=nav, **fields)
        batch = ScanBatch(self.scans, times, truth, nav, **fields)
        self.mapper.add(batch)
        self._batches.append(batch)
        positions = np.concatenate([[self.truth[-1][:3, 3]], truth[:, :3, 3]])
        self.path_m += float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
        self.truth.append(truth[-1])
        self.nav.append(nav[-1])
        self.scans += len(truth)


def _near(poses: np.ndarray, target: np.ndarray, config: ControllerConfig = ControllerConfig()) -> np.ndarray:
    """Whether each pose (S,4,4) is within the controller's tolerances of target (x, y, z, yaw)."""
    yaw = yaw_pitch_roll(poses[:, :3, :3])[:, 0]
    turn = np.abs((target[3] - yaw + np.pi) % (2 * np.pi) - np.pi)
    return (np.linalg.norm(poses[:, :3, 3] - target[:3], axis=1) < config.tolerance_m) & (turn < config.tolerance_rad)


def _write_csv(path: Path, rows: list) -> None:
    with AtomicPath(path) as temporary:
        with open(temporary, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
