"""The receding-horizon next-best-view planner (Bircher et al.'s nbvplanner, with Ho's
changes for a profiling sonar: thesis 4.5.3-4.5.4, IROS IV-B), with a time-aware choice of
branch (FUEL's edge times).

Each `plan` grows an RRT from the vehicle's pose inside the exploration box. A node is a
vehicle state (x, y, z, yaw); Visible(edge) is the volume of unknown voxels the sonar would see
from the views sampled along its edge (it sees a plane, so gain accrues while the vehicle
moves and turns; the views turn at a steady rate along the straight edge, as the vehicle flies
it with `yaw_along_path`). Two rules choose the branch the vehicle takes:

- "gain_rate" (default): a node's value is its branch's gain per second of flight,

      Rate(n_k) = sum of Visible(edge j), j <= k  /  sum of T(edge j), j <= k,
      T(edge) = max(length / v_max, |turn| / yaw_rate_max) + overhead,

  the time to fly the edge under the vehicle's speed and yaw-rate limits (FUEL's cost) plus
  the stop at its waypoint. A turn that takes longer than its translation costs its time, so
  the vehicle turns in place only where nothing better per second is in reach.
- "discounted" (the papers'): its parent's gain plus the edge's discounted by the traversal
  cost from the vehicle (IROS Eq. 7 with nbvplanner's discount),

      Gain(n_k) = Gain(n_k-1) + Visible(edge k) * exp(-lambda * d(n_k)),

  d summing the edges' costs: an edge costs its length, or, if longer, the distance the
  vehicle would fly in the time its turn takes (turn_cost_m_per_rad).

Samples are constrained: in the x-y plane at the vehicle's depth (a share of them climbing
or descending within the sensor's look up or down, `sloped_fraction`) or along z at its x, y,
with the heading within a bound of the parent's; with `yaw_along_path`, also within what the
vehicle can turn while it flies the edge's translation (yaw-rate limit times the
translation's time), so the yaw is planned along the path and no edge is a turn in place. An
edge enters the tree only if the collision box swept along it is free in the map. The tree
stops at N_max nodes once its best branch gains something, else at N_tol. The vehicle flies
the best branch's first edge; the rest seeds the next tree. When the best score is low (or
nothing gains), `reposition` offers a global step over the explored graph (`graph.py`).

Trees grow in rounds, each of as many samples as half the tree's nodes (one, then one, two,
three, ...; at least min_round_samples, at most N_max), each attached to the nearest node of
the tree before the round: a round's collision checks and gains are one launch each, and
branches still get deep.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from vogjax.config.planner import PlannerConfig
from vogjax.geometry import rigid_poses, wrap_angle, yaw_pitch_roll
from vogjax.kernels import hashing
from vogjax.maps import VogMap
from vogjax.maps.blockmap import FREE, OCCUPIED, UNKNOWN
from vogjax.planner.collision import clear_edges
from vogjax.planner.gain import check_region, edge_counts, gain_range
from vogjax.planner.graph import ExploredGraph
from vogjax.planner.source import MapLike, check_map, opened
from vogjax.sensors import ProfilingSonar, RangeSensor, as_sensor
from vogjax.validation import float_array, within_key_range


@dataclasses.dataclass(frozen=True)
class Plan:
    """A planning iteration's result.

    Attributes
    ----------
    waypoints : numpy.ndarray, (K, 4) float
        x, y, z, yaw of the best branch's nodes, nearest first (fly the first; empty when no
        edge was collision-free).
    gain_m3 : float
        The best branch's gain: discounted (the "discounted" rule) or summed over its edges
        ("gain_rate").
    nodes : int
        Nodes grown, the root excluded (a global step: the trip's vertices).
    iterations : int
        Samples drawn, remembered nodes included (a global step: the candidates counted).
    rays : int
        Gain rays cast.
    seconds : float
        Wall time of the plan.
    tree_states : numpy.ndarray, (N+1, 4) float
        The whole tree's states (x, y, z, yaw), the root first, for plots.
    tree_parents : numpy.ndarray, (N+1,) int
        Each state's parent (-1: the root's).
    score : float
        The value the rule maximised: gain_m3 for "discounted", m^3 per second for "gain_rate".
    first_edge_m3 : float
        Unknown volume the first edge's views would see (what flying it should reveal), m^3.
    branch_s : float
        Time to fly the best branch under the vehicle's limits, seconds.
    """

    waypoints: np.ndarray
    gain_m3: float
    nodes: int
    iterations: int
    rays: int
    seconds: float
    tree_states: np.ndarray
    tree_parents: np.ndarray
    score: float = 0.0
    first_edge_m3: float = 0.0
    branch_s: float = 0.0


def state_of_pose(T_world_vehicle: np.ndarray) -> np.ndarray:
    """(4,) x, y, z, yaw of a vehicle pose."""
    return np.r_[T_world_vehicle[:3, 3], yaw_pitch_roll(T_world_vehicle[:3, :3])[0]]


class NbvPlanner:
    """A receding-horizon next-best-view planner (nbvplanner's RRT with Ho's changes for a
    profiling sonar, a time-aware rule by default, and a global step over the explored graph).

    Parameters
    ----------
    config : PlannerConfig, optional
        The planner's settings (default: `PlannerConfig()`, the time-aware rule).
    bounds : array_like, (2, 3) float
        The exploration box (lower, upper corner, metres) the vehicle's box stays in; required.
    sensor : RangeSensor, optional
        The sensor whose views gain (default: the papers' profiling sonar); it must have fixed
        beams.
    region : array_like, (2, 3) float, optional
        Where gain counts (default: everywhere).
    risk : callable, optional
        ``risk(starts (E,3), ends (E,3)) -> (E,)`` collision risk >= 0 of edges, weighted by
        ``config.risk_weight`` (required when that is > 0).

    Attributes
    ----------
    config : PlannerConfig
        The settings.
    bounds : numpy.ndarray, (2, 3) float
        The exploration box.
    sample_box : numpy.ndarray, (2, 3) float
        Where nodes may lie: the bounds shrunk by half the collision box.
    sensor : RangeSensor
        The sensor of the gain.
    region : numpy.ndarray or None
        Where gain counts.
    memory : numpy.ndarray, (K, 4) float
        The rest of the last best branch, which seeds the next tree.
    graph : ExploredGraph
        Every tree so far and the states visited, for global steps.

    Raises
    ------
    ValueError
        If config is not a PlannerConfig, bounds is missing, malformed or smaller than the
        collision box, the sensor has no fixed beams or its range is below gain_range_m, region
        is malformed, or risk_weight > 0 without a callable risk.
    """

    def __init__(
        self,
        config: PlannerConfig | None = None,
        bounds: npt.ArrayLike | None = None,
        sensor: RangeSensor | None = None,
        region: npt.ArrayLike | None = None,
        risk: Callable[[np.ndarray, np.ndarray], npt.ArrayLike] | None = None,
    ) -> None:
        self.config = config = config or PlannerConfig()
        if not isinstance(config, PlannerConfig):
            raise ValueError(f"config must be a PlannerConfig, got {type(config).__name__}")
        if bounds is None:
            raise ValueError("bounds must be given: the (2,3) exploration box")
        bounds = float_array("bounds", bounds, (2, 3), np.float64)
        half = np.array(config.box_m) / 2
        self.bounds = bounds
        self.sample_box = np.stack([bounds[0] + half, bounds[1] - half])
        if np.any(self.sample_box[0] > self.sample_box[1]):
            raise ValueError("bounds must be larger than the collision box on every axis")
        self.sensor = ProfilingSonar() if sensor is None else as_sensor(sensor)
        try:  # one without fixed beams (a recorded point cloud) is refused here, not mid-plan
            self.sensor.beam_directions()
        except ValueError as error:
            raise ValueError(f"sensor: {error}") from None
        gain_range("PlannerConfig.gain_range_m", self.sensor, config.gain_range_m)
        self.region = check_region(region)
        if config.risk_weight > 0 and not callable(risk):
            raise ValueError("risk must be a callable when PlannerConfig.risk_weight > 0")
        self.risk = risk
        self.rng = np.random.default_rng(config.seed)
        # how steeply the sensor's beams look up and down (climbs and descents per metre that
        # keep the layer the vehicle travels in one its fan has seen)
        beams = self.sensor.beam_directions().reshape(-1, 3) @ self.sensor.T_vehicle_sensor[:3, :3].T
        elevation = np.arcsin(np.clip(beams[:, 2], -1.0, 1.0))
        self.slopes = np.tan(np.clip([elevation.max(), -elevation.min()], 0.0, np.pi / 4))
        self.memory = np.zeros((0, 4))  # the rest of the last best branch
        self._obstacle_margins = config.obstacle_margins_m()  # each plan sets them for its drift
        self._min_edge_m = config.min_edge_length_m  # 0 while a blocked plan is retried
        self.graph = ExploredGraph(config)  # every tree so far, for global steps

    def reset(self) -> None:
        """Forget the last best branch (e.g. after the vehicle was moved by hand)."""
        self.memory = np.zeros((0, 4))

    def reposition(self, map_: MapLike, T_world_vehicle: npt.ArrayLike, candidates: int = 48, tries: int = 8) -> Plan:
        """A global step: a trip over the explored graph to the vertex the trees left behind
        with the most gain per second of the whole trip (GBPlanner's repositioning), for when
        the local tree finds little left to see.

        The `candidates` most promising unvisited vertices farther than an edge from the vehicle
        have their tree edge's gain counted again on `map_`; the trip to each is the quickest
        path through the graph (edge times under the vehicle's limits). Of the best `tries`
        trips, the first whose edges not flown before are all collision-free in `map_` now (each
        checked with the clearance around its own start, where the vehicle will be) is returned.

        Parameters
        ----------
        map_ : vj.VoxelMap, vj.GlobalMap, vj.VogMap or vogjax.planner.Overlay
            The map the trip's gains and collision checks read (level 0).
        T_world_vehicle : array_like, (4, 4) float
            Where the vehicle is (a plan from it came just before: it is the graph's last vertex).
        candidates : int
            Unvisited vertices whose gain is counted again.
        tries : int
            Trips checked for collisions, best first.

        Returns
        -------
        Plan
            waypoints: the trip's vertices (empty when no trip is clear or has gain); gain_m3:
            the target edge's gain; score: gain per second of the trip; branch_s: its time.

        Raises
        ------
        ValueError
            If the map is not one the planner reads or the pose is not rigid.
        """
        check_map(map_)
        cfg = self.config
        root = state_of_pose(rigid_poses("T_world_vehicle", T_world_vehicle)[0])
        start_s = time.perf_counter()
        empty = np.zeros((0, 4))
        if not cfg.global_step or len(self.graph) == 0:
            return Plan(empty, 0.0, 0, 0, 0, time.perf_counter() - start_s, root[None], np.array([-1]))
        start = self.graph.last_visit
        pool = self.graph.candidates(root[:3], candidates, cfg.edge_length_m)
        rays, unknown = 0, np.zeros(len(pool))
        with opened(map_) as source:
            gains = np.zeros(len(pool))
            if len(pool):
                parents = self.graph.states[self.graph.parent[pool]]
                counts, rays = edge_counts(
                    source,
                    parents,
                    self.graph.states[pool],
                    self.sensor,
                    cfg.gain_step_m,
                    cfg.gain_range_m,
                    self.region,
                    frontier=cfg.gain == "frontier",
                    states=self._counted_states(),
                )
                gains, unknown = self._visible(counts, source.config.voxel_size)
                self.graph.promised[pool] = gains  # what they promise now
            for trip in self.graph.trips(start, pool, gains)[:tries]:
                hops = np.vstack([root, trip.states])
                fresh = np.flatnonzero(~trip.flown)
                clear = all(
                    clear_edges(
                        source,
                        hops[k][None, :3],
                        hops[k + 1][None, :3],
                        np.array(cfg.checked_box_m),
                        hops[k][:3],
                        cfg.clearance_m,
                        layer_only=not cfg.blind_vertical,
                        obstacle_margin_m=self._obstacle_margins,
                    )[0]
                    for k in fresh
                )
                if not clear:
                    continue
                self.memory = empty  # the next tree grows from where the trip ends
                target = int(np.flatnonzero(pool == trip.vertices[-1])[0])
                return Plan(
                    trip.states,
                    trip.gain_m3,
                    len(trip.states),
                    len(pool),
                    rays,
                    time.perf_counter() - start_s,
                    hops,
                    np.arange(-1, len(trip.states)),
                    trip.rate,
                    float(unknown[target]),
                    trip.seconds,
                )
        return Plan(empty, 0.0, 0, len(pool), rays, time.perf_counter() - start_s, root[None], np.array([-1]))

    def arrived(self, state: npt.ArrayLike) -> None:
        """Record that the vehicle reached a vertex of a global step's trip.

        Parameters
        ----------
        state : array_like, (4,) float
            x, y, z, yaw of the trip's vertex reached: a visited vertex of the explored graph,
            joined to the last by the motion flown.
        """
        self.graph.visit(float_array("state", state, (4,), np.float64))

    def _counted_states(self) -> tuple[int, ...]:
        """The states whose voxels a plan's gain reads (the counts' columns): unknown always (its
        volume is kept per node), free and occupied only where they are weighted. The view-gain
        kernel counts only these, so the free voxels a view sees cost no set insertions."""
        cfg = self.config
        if cfg.gain == "frontier":
            return (UNKNOWN,)
        return (UNKNOWN,) + ((FREE,) if cfg.gain_free else ()) + ((OCCUPIED,) if cfg.gain_occupied else ())

    def _visible(self, counts: np.ndarray, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
        """Gains (the configured kind) and unknown volumes (m^3) of edges' counts (E,4), counted
        for `_counted_states` (the others' columns are -1 and not read)."""
        cfg = self.config
        voxel_m3 = voxel_size**3
        unknown_m3 = counts[:, 0] * voxel_m3
        if cfg.gain == "frontier":
            return counts[:, 3] * voxel_m3, unknown_m3
        # the terms of zero weight, which added +0.0 before, are left out: the same sums
        weighted = cfg.gain_unknown * counts[:, 0]
        if cfg.gain_free:
            weighted = weighted + cfg.gain_free * counts[:, 1]
        if cfg.gain_occupied:
            weighted = weighted + cfg.gain_occupied * counts[:, 2]
        return weighted * voxel_m3, unknown_m3

    def plan(self, map_: MapLike, T_world_vehicle: npt.ArrayLike, drift_m: float = 0.0) -> Plan:
        """Grow a tree from the vehicle's pose and return its best branch.

        The remembered rest of the last best branch seeds the tree; rounds of samples grow it
        to N_max nodes once its best branch gains something (else to N_tol). A tree that gains
        nothing under the drift margin or the shortest edge is grown again without them (both
        are preferences; the box and its margins stay).

        Parameters
        ----------
        map_ : vj.VoxelMap, vj.GlobalMap, vj.VogMap or vogjax.planner.Overlay
            The map; collision checks and gain rays read its `collision_level` and `gain_level`
            (coarse levels need a VoxelMap, GlobalMap or VogMap).
        T_world_vehicle : array_like, (4, 4) float
            The vehicle's (estimated) pose.
        drift_m : float, optional
            How far (one sigma, x-y, metres) the vehicle's estimate may have drifted from where
            the map put what it holds: occupied voxels are kept `drift_margin_sigmas` times it
            farther off (at most max_drift_margin_m).

        Returns
        -------
        Plan
            The best branch (waypoints, nearest first), its gain, score and time, and the tree.

        Raises
        ------
        ValueError
            If the map is not one the planner reads (or has no coarse level asked for), the
            pose is not rigid, drift_m is negative or not finite, or the bounds and range would
            leave the map's key range.
        """
        check_map(map_)
        if (
            isinstance(drift_m, (bool, np.bool_))
            or not isinstance(drift_m, (int, float, np.integer, np.floating))
            or not (np.isfinite(drift_m) and drift_m >= 0)
        ):
            raise ValueError(f"drift_m must be a non-negative number, got {drift_m!r}")
        root = state_of_pose(rigid_poses("T_world_vehicle", T_world_vehicle)[0])  # before any change
        # what planning changes, put back if it raises midway (a risk callable's NaN): the next
        # plan is then the one a planner that never tried would make
        saved = (self.rng.bit_generator.state, self._obstacle_margins, self._min_edge_m)
        self._obstacle_margins = self.config.obstacle_margins_m(float(drift_m))
        start_s = time.perf_counter()
        cfg = self.config
        # the levels collision checks and gain rays read (PlannerConfig.collision_level,
        # gain_level): a VogMap's coarse map brought up to date once, before any lock is taken
        levels_map = map_.coarse_map() if isinstance(map_, VogMap) and cfg.collision_level + cfg.gain_level else map_
        with contextlib.ExitStack() as stack:
            levels = {0: stack.enter_context(opened(map_))}
            for level in sorted({cfg.collision_level, cfg.gain_level} - {0}):
                levels[level] = stack.enter_context(opened(levels_map, level))
            source, sources = levels[0], (levels[cfg.collision_level], levels[cfg.gain_level])
            # checked before the first sample is drawn: a refused plan leaves the random state
            reach = np.abs(self.bounds).max() + self.config.gain_range_m + np.max(self.config.checked_box_m)
            within_key_range("bounds", np.array([reach]), source.config.voxel_size, hashing.VOXEL_KEY_LIMIT)
            try:
                tree, rays, iterations = self._grow_tree(sources, root)
                relaxed = cfg.obstacle_margins_m()
                if tree.scores.max() <= 0 and (self._obstacle_margins != relaxed or cfg.min_edge_length_m > 0):
                    # blocked or gaining nothing under the drift margin or the shortest edge: both
                    # are preferences (a tight corner may leave only short ways out), the box and
                    # its margins are not
                    self._obstacle_margins, self._min_edge_m = relaxed, 0.0
                    tree, more_rays, more_iterations = self._grow_tree(sources, root)
                    rays, iterations = rays + more_rays, iterations + more_iterations
                    self._min_edge_m = cfg.min_edge_length_m
            except BaseException:
                self.rng.bit_generator.state, self._obstacle_margins, self._min_edge_m = saved
                raise
        if cfg.global_step:  # the explored graph keeps the tree: where a later global step may go
            self.graph.add_tree(self.graph.visit(root), tree.states, tree.parents, tree.visible)
        best = int(np.argmax(tree.scores))
        branch = tree.branch(best)
        self.memory = branch[1:]
        first = tree.first_node(best)
        return Plan(
            branch,
            float(tree.gains[best]),
            len(tree.states) - 1,
            iterations,
            rays,
            time.perf_counter() - start_s,
            tree.states.copy(),
            tree.parents.copy(),
            float(tree.scores[best]),
            float(tree.unknown[first]) if first > 0 else 0.0,
            float(tree.times[best]),
        )

    def _grow_tree(self, sources, root: np.ndarray) -> tuple[_Tree, int, int]:
        """A tree from `root` (sources: the opened maps of the collision checks and of the gain
        rays): the remembered branch, then rounds of samples until N_max nodes gain something,
        N_tol nodes are grown or the attempts run out. Returns the tree, the gain rays cast and
        the samples drawn."""
        cfg = self.config
        tree = _Tree(root, cfg)
        rays = self._grow(sources, tree, self.memory, root, chain=True)
        iterations = len(self.memory)
        while True:
            nodes = len(tree.states) - 1
            if nodes >= cfg.tolerance_nodes or (nodes >= cfg.max_nodes and tree.scores.max() > 0):
                break
            if iterations >= cfg.tolerance_nodes * cfg.attempts_per_node:
                break
            count = min(cfg.max_nodes, max((len(tree.states) + 1) // 2, cfg.min_round_samples))
            rays += self._grow(sources, tree, self._samples(root, count), root, chain=False)
            iterations += count
        return tree, rays, iterations

    # ---------------------------------------------------------------- sampling
    def _samples(self, root: np.ndarray, count: int) -> np.ndarray:
        """`count` targets (x, y, z, yaw offset, slope): in the x-y plane at the vehicle's depth,
        or along z at its x, y (thesis 4.5.3); yaw offsets within the heading bound; slope NaN.
        With sloped_fraction > 0 the x-y samples leave from the depth of the node they attach to
        instead: level (slope 0) or, for that share of them, climbing (> 0) or descending (< 0)
        per metre of horizontal travel within the sensor's look up or down."""
        cfg, lo, hi = self.config, *self.sample_box
        targets = np.full((count, 5), np.nan)
        vertical = self.rng.random(count) < cfg.vertical_fraction
        targets[:, :2] = np.where(vertical[:, None], root[:2], self.rng.uniform(lo[:2], hi[:2], (count, 2)))
        targets[:, 2] = np.where(vertical, self.rng.uniform(lo[2], hi[2], count), np.clip(root[2], lo[2], hi[2]))
        targets[:, 3] = self.rng.uniform(-cfg.max_heading_change_rad, cfg.max_heading_change_rad, count)
        if cfg.sloped_fraction > 0:  # no draws otherwise: the papers' samples stay as they were
            # x-y samples leave from the depth of the node they attach to, level or sloped
            sloped = ~vertical & (self.rng.random(count) < cfg.sloped_fraction)
            u = self.rng.uniform(-1.0, 1.0, count)
            targets[~vertical, 4] = 0.0
            targets[sloped, 4] = np.where(u > 0, u * self.slopes[0], u * self.slopes[1])[sloped]
        return targets

    def _grow(self, sources, tree: _Tree, targets: np.ndarray, root: np.ndarray, chain: bool) -> int:
        """Steer, check and add edges toward `targets` (sources: the opened maps of the collision
        checks and of the gain rays). With `chain`, targets (x, y, z, yaw) are
        one branch from the root (the remembered one: it breaks at its first edge that is too
        long, turns too far or collides); else each target (x, y, z, yaw offset) attaches to its
        nearest node. Returns the gain rays cast."""
        if len(targets) == 0:
            return 0
        cfg = self.config
        if chain:
            parents = None
            starts = np.vstack([root, targets[:-1]])
        else:
            parents = _nearest(tree.states[:, :3], targets[:, :3])
            starts = tree.states[parents]
            sloped = np.isfinite(targets[:, 4])
            if sloped.any():  # climb or descend from the node it attaches to
                targets = targets.copy()
                flat = np.linalg.norm(targets[sloped, :2] - starts[sloped, :2], axis=1)
                targets[sloped, 2] = np.clip(
                    starts[sloped, 2] + targets[sloped, 4] * flat, self.sample_box[0][2], self.sample_box[1][2]
                )
        step = targets[:, :3] - starts[:, :3]
        scale = np.minimum(1.0, cfg.edge_length_m / np.maximum(np.linalg.norm(step, axis=1), 1e-12))
        turn = targets[:, 3]
        if cfg.yaw_along_path and not chain:
            # the heading changes while the vehicle translates: an edge turns at most as far as
            # the yaw-rate limit allows in the time its translation takes (no turn in place)
            length = np.linalg.norm(step, axis=1) * scale
            allowed = np.minimum(cfg.max_heading_change_rad, cfg.max_yaw_rate_rps * length / cfg.max_speed_mps)
            turn = turn * (allowed / max(cfg.max_heading_change_rad, 1e-12))
        ends = np.c_[starts[:, :3] + step * scale[:, None], targets[:, 3] if chain else wrap_angle(starts[:, 3] + turn)]
        ok = np.all((ends[:, :3] >= self.sample_box[0] - 1e-9) & (ends[:, :3] <= self.sample_box[1] + 1e-9), axis=1)
        if self._min_edge_m > 0 and not chain:  # a shorter edge is no motion the controller flies
            ok &= np.linalg.norm(ends[:, :3] - starts[:, :3], axis=1) >= self._min_edge_m
        if chain:
            ok &= (scale >= 1.0) & (np.abs(wrap_angle(ends[:, 3] - starts[:, 3])) <= cfg.max_heading_change_rad + 1e-9)
            ok = np.cumprod(ok).astype(bool)
        box = np.array(cfg.checked_box_m)
        collide, see = sources
        ok[ok] = clear_edges(
            collide,
            starts[ok, :3],
            ends[ok, :3],
            box,
            root[:3],
            cfg.clearance_m,
            layer_only=not cfg.blind_vertical,
            obstacle_margin_m=self._obstacle_margins,
        )
        if chain:
            ok = np.cumprod(ok).astype(bool)
        if not ok.any():
            return 0
        counts, rays = edge_counts(
            see,
            starts[ok],
            ends[ok],
            self.sensor,
            cfg.gain_step_m,
            cfg.gain_range_m,
            self.region,
            frontier=cfg.gain == "frontier",
            states=self._counted_states(),
        )
        visible, unknown_m3 = self._visible(counts, see.config.voxel_size)
        if cfg.risk_weight > 0:
            risk = np.asarray(self.risk(starts[ok, :3], ends[ok, :3]), np.float64)
            if risk.shape != (int(ok.sum()),) or not np.all(np.isfinite(risk)) or np.any(risk < 0):
                raise ValueError("risk must return one finite, non-negative value per edge")
            visible = visible * np.exp(-cfg.risk_weight * risk)
        for k, edge in enumerate(np.flatnonzero(ok)):
            # a chain's edges are added in order: each hangs off the node added just before
            parent = (0 if edge == 0 else len(tree.states) - 1) if chain else int(parents[edge])
            tree.add(parent, ends[edge], visible[k], unknown_m3[k])
        return rays


def _nearest(nodes: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Index of the nearest of `nodes` (N,3) to each target (T,3) (the first on a tie), in
    chunks of targets that keep the distance table near 12 MiB (24 bytes a node and target)."""
    chunk = max(1, (1 << 19) // max(len(nodes), 1))
    return np.concatenate(
        [
            np.argmin(np.linalg.norm(nodes[None] - targets[k : k + chunk, None], axis=2), axis=1)
            for k in range(0, len(targets), chunk)
        ]
    )


class _Tree:
    """Nodes (x, y, z, yaw), parents, and per node: its edge's gain and unknown volume, the traversal
    cost from the root (m, the discount's d), the time to fly there (s), its branch's gain
    (discounted for the papers' rule, summed for the rate rule) and the rule's score."""

    def __init__(self, root: np.ndarray, config: PlannerConfig):
        self.config = config
        self.states = root[None].copy()
        self.parents = np.array([-1])
        self.visible = np.zeros(1)
        self.unknown = np.zeros(1)
        self.distances = np.zeros(1)
        self.times = np.zeros(1)
        self.gains = np.zeros(1)
        self.scores = np.zeros(1)

    def add(self, parent: int, state: np.ndarray, visible_m3: float, unknown_m3: float) -> None:
        cfg = self.config
        origin = self.states[parent]
        length, turn = float(np.linalg.norm(state[:3] - origin[:3])), abs(wrap_angle(state[3] - origin[3]))
        distance = self.distances[parent] + max(length, cfg.turn_cost_m_per_rad * turn)
        seconds = self.times[parent] + cfg.edge_seconds(length, turn)
        if cfg.selection == "discounted":
            gain = self.gains[parent] + visible_m3 * np.exp(-cfg.discount * distance)
            score = gain
        else:
            gain = self.gains[parent] + visible_m3
            score = gain / seconds
        self.states = np.vstack([self.states, state])
        self.parents = np.r_[self.parents, parent]
        self.visible = np.r_[self.visible, visible_m3]
        self.unknown = np.r_[self.unknown, unknown_m3]
        self.distances = np.r_[self.distances, distance]
        self.times = np.r_[self.times, seconds]
        self.gains = np.r_[self.gains, gain]
        self.scores = np.r_[self.scores, score]

    def first_node(self, node: int) -> int:
        """The root's child on the branch to `node` (0 for the root)."""
        while node > 0 and self.parents[node] > 0:
            node = int(self.parents[node])
        return node

    def branch(self, node: int) -> np.ndarray:
        """(K,4) states from the root's child to `node` (empty for the root)."""
        path = []
        while node > 0:
            path.append(self.states[node])
            node = int(self.parents[node])
        return np.array(path[::-1]).reshape(-1, 4)
