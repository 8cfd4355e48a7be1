"""The receding-horizon next-best-view planner (Bircher et al.'s nbvplanner, with Ho's
changes for a profiling sonar: thesis 4.5.3-4.5.4, IROS IV-B).

Each `plan` grows an RRT from the vehicle's pose inside the exploration box. A node is a
vehicle state (x, y, z, yaw); its gain is its parent's plus the edge's view gain discounted by
the traversal cost from the vehicle (IROS Eq. 7 with nbvplanner's discount):

    Gain(n_k) = Gain(n_k-1) + Visible(edge k) * exp(-lambda * d(n_k))

where Visible is the volume of unknown voxels the sonar would see from the views sampled along
the edge (it sees a plane, so gain accrues while the vehicle moves), and d sums the edges'
costs: an edge costs its length, or, if longer, the distance the vehicle would fly in the time
its turn takes (nbvplanner counts length only; then turning in place is free, and a vehicle
with a profiling sonar spends minutes sweeping the fan on the spot for small gains).

Samples are constrained: in the x-y plane at the vehicle's depth or along z at its x, y, with
the heading within a bound of the parent's. An edge enters the tree only if the collision box
swept along it is free in the map. The tree stops at N_max nodes once its best branch gains
something, else at N_tol. The vehicle flies the best branch's first edge; the rest seeds the
next tree.

Trees grow in rounds, each of as many samples as half the tree's nodes (one, then one, two,
three, ...; at most N_max), each attached to the nearest node of the tree before the round: a
round's collision checks and gains are one launch each, and branches still get deep.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

import numpy as np

from vogjax.config.planner import PlannerConfig
from vogjax.geometry import rigid_poses, wrap_angle, yaw_pitch_roll
from vogjax.kernels import hashing
from vogjax.maps import VogMap
from vogjax.planner.collision import clear_edges
from vogjax.planner.gain import check_region, edge_counts, gain_range
from vogjax.planner.source import check_map, opened
from vogjax.sensors import ProfilingSonar, RangeSensor, as_sensor
from vogjax.validation import float_array, within_key_range


@dataclasses.dataclass(frozen=True)
class Plan:
    """waypoints (K,4): x, y, z, yaw of the best branch's nodes, nearest first (fly the first;
    empty when no edge was collision-free or none gains anything); gain_m3: the best branch's discounted gain;
    nodes: nodes grown (the vehicle's root excluded); iterations: samples drawn (remembered
    nodes included); rays: gain rays cast; seconds: wall time of the plan; tree_states (N+1,4)
    and tree_parents (N+1,) (-1 for the root): the whole tree, for plots."""

    waypoints: np.ndarray
    gain_m3: float
    nodes: int
    iterations: int
    rays: int
    seconds: float
    tree_states: np.ndarray
    tree_parents: np.ndarray


def state_of_pose(T_world_vehicle: np.ndarray) -> np.ndarray:
    """(4,) x, y, z, yaw of a vehicle pose."""
    return np.r_[T_world_vehicle[:3, 3], yaw_pitch_roll(T_world_vehicle[:3, :3])[0]]


class NbvPlanner:
    """config: PlannerConfig; bounds (2,3): the exploration box the vehicle's box stays in;
    sensor: the RangeSensor whose gain counts (default: the papers' profiling sonar);
    region (2,3): where gain counts (default: everywhere); risk: optional callable(starts (E,3),
    ends (E,3)) -> (E,) collision risk >= 0 of edges (weighted by config.risk_weight)."""

    def __init__(
        self,
        config: PlannerConfig | None = None,
        bounds=None,
        sensor: RangeSensor | None = None,
        region=None,
        risk=None,
    ):
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
        self.memory = np.zeros((0, 4))  # the rest of the last best branch

    def reset(self) -> None:
        """Forget the last best branch (e.g. after the vehicle was moved by hand)."""
        self.memory = np.zeros((0, 4))

    def plan(self, map_, T_world_vehicle) -> Plan:
        """Grow a tree from T_world_vehicle (4,4) in `map_` (a VoxelMap, GlobalMap, VogMap or
        Overlay) and return the best branch."""
        check_map(map_)
        root = state_of_pose(rigid_poses("T_world_vehicle", T_world_vehicle)[0])
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
            reach = (
                np.abs(self.bounds).max() + self.config.gain_range_m + np.max(self.config.box_m) + self.config.margin_m
            )
            within_key_range("bounds", np.array([reach]), source.config.voxel_size, hashing.VOXEL_KEY_LIMIT)
            tree = _Tree(root)
            rays = self._grow(sources, tree, self.memory, root, chain=True)
            iterations = len(self.memory)
            cfg = self.config
            while True:
                nodes = len(tree.states) - 1
                if nodes >= cfg.tolerance_nodes or (nodes >= cfg.max_nodes and tree.gains.max() > 0):
                    break
                if iterations >= cfg.tolerance_nodes * cfg.attempts_per_node:
                    break
                count = min(cfg.max_nodes, (len(tree.states) + 1) // 2)
                rays += self._grow(sources, tree, self._samples(root, count), root, chain=False)
                iterations += count
        branch = tree.branch(int(np.argmax(tree.gains)))
        self.memory = branch[1:]
        return Plan(
            branch,
            float(tree.gains.max()),
            len(tree.states) - 1,
            iterations,
            rays,
            time.perf_counter() - start_s,
            tree.states.copy(),
            tree.parents.copy(),
        )

    # ---------------------------------------------------------------- sampling
    def _samples(self, root: np.ndarray, count: int) -> np.ndarray:
        """`count` targets (x, y, z, yaw offset): in the x-y plane at the vehicle's depth, or
        along z at its x, y (thesis 4.5.3); yaw offsets within the heading bound."""
        cfg, lo, hi = self.config, *self.sample_box
        targets = np.empty((count, 4))
        vertical = self.rng.random(count) < cfg.vertical_fraction
        targets[:, :2] = np.where(vertical[:, None], root[:2], self.rng.uniform(lo[:2], hi[:2], (count, 2)))
        targets[:, 2] = np.where(vertical, self.rng.uniform(lo[2], hi[2], count), np.clip(root[2], lo[2], hi[2]))
        targets[:, 3] = self.rng.uniform(-cfg.max_heading_change_rad, cfg.max_heading_change_rad, count)
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
        step = targets[:, :3] - starts[:, :3]
        scale = np.minimum(1.0, cfg.edge_length_m / np.maximum(np.linalg.norm(step, axis=1), 1e-12))
        ends = np.c_[
            starts[:, :3] + step * scale[:, None], targets[:, 3] if chain else wrap_angle(starts[:, 3] + targets[:, 3])
        ]
        ok = np.all((ends[:, :3] >= self.sample_box[0] - 1e-9) & (ends[:, :3] <= self.sample_box[1] + 1e-9), axis=1)
        if chain:
            ok &= (scale >= 1.0) & (np.abs(wrap_angle(ends[:, 3] - starts[:, 3])) <= cfg.max_heading_change_rad + 1e-9)
            ok = np.cumprod(ok).astype(bool)
        box = np.array(cfg.box_m) + 2 * cfg.margin_m
        collide, see = sources
        ok[ok] = clear_edges(collide, starts[ok, :3], ends[ok, :3], box, root[:3], cfg.clearance_m)
        if chain:
            ok = np.cumprod(ok).astype(bool)
        if not ok.any():
            return 0
        counts, rays = edge_counts(
            see, starts[ok], ends[ok], self.sensor, cfg.gain_step_m, cfg.gain_range_m, self.region
        )
        visible = (
            cfg.gain_unknown * counts[:, 0] + cfg.gain_free * counts[:, 1] + cfg.gain_occupied * counts[:, 2]
        ) * see.config.voxel_size**3
        if cfg.risk_weight > 0:
            risk = np.asarray(self.risk(starts[ok, :3], ends[ok, :3]), np.float64)
            if risk.shape != (int(ok.sum()),) or not np.all(np.isfinite(risk)) or np.any(risk < 0):
                raise ValueError("risk must return one finite, non-negative value per edge")
            visible = visible * np.exp(-cfg.risk_weight * risk)
        for k, edge in enumerate(np.flatnonzero(ok)):
            # a chain's edges are added in order: each hangs off the node added just before
            parent = (0 if edge == 0 else len(tree.states) - 1) if chain else int(parents[edge])
            tree.add(parent, ends[edge], visible[k], cfg.discount, cfg.turn_cost_m_per_rad)
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
    """Nodes (x, y, z, yaw), parents, traversal costs from the root (m) and discounted branch
    gains."""

    def __init__(self, root: np.ndarray):
        self.states = root[None].copy()
        self.parents = np.array([-1])
        self.distances = np.zeros(1)
        self.gains = np.zeros(1)

    def add(self, parent: int, state: np.ndarray, visible_m3: float, discount: float, turn_cost: float) -> None:
        origin = self.states[parent]
        cost = max(float(np.linalg.norm(state[:3] - origin[:3])), turn_cost * abs(wrap_angle(state[3] - origin[3])))
        distance = self.distances[parent] + cost
        self.states = np.vstack([self.states, state])
        self.parents = np.r_[self.parents, parent]
        self.distances = np.r_[self.distances, distance]
        self.gains = np.r_[self.gains, self.gains[parent] + visible_m3 * np.exp(-discount * distance)]

    def branch(self, node: int) -> np.ndarray:
        """(K,4) states from the root's child to `node` (empty for the root)."""
        path = []
        while node > 0:
            path.append(self.states[node])
            node = int(self.parents[node])
        return np.array(path[::-1]).reshape(-1, 4)
