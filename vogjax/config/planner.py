"""Settings of the next-best-view planner (`vogjax.planner.NbvPlanner`).

Defaults are Ho's propeller experiment (thesis Table 4.2, IROS Table I): 2 m RRT edges,
N_max = 15, lambda = 0.5, a planner sensor range of 5 m and a 1.0 x 1.0 x 0.5 m collision box.
For the tank (thesis Table 4.4) use edge_length_m = 1.0, gain_range_m = 5.63, discount = 0.
"""

from __future__ import annotations

import dataclasses

from vogjax.config.pipeline import PipelineConfig
from vogjax.config.schema import Config, integer, non_negative, number, positive, section
from vogjax.config.sim import ControllerConfig

# The most nodes a tree may grow to: each round finds its samples' nearest nodes among all of
# them, and the work grows with the square of the tree (the papers use N_tol of 60 or so).
MAX_TREE_NODES = 10_000


@dataclasses.dataclass(frozen=True)
class PlannerConfig(Config):
    """edge_length_m: longest RRT edge (the extension range), metres.
    max_nodes: N_max, nodes the tree grows to when its best branch gains something.
    tolerance_nodes: N_tol, nodes it may grow to while the best gain stays zero.
    attempts_per_node: samples allowed per wanted node before giving up (collisions reject many).
    discount: lambda of the gain formula: an edge's gain counts exp(-lambda * d), d the
        traversal cost from the vehicle to the edge's end along the branch, metres (nbvplanner's
        discount; turns count through turn_cost_m_per_rad).
    turn_cost_m_per_rad: what a turn adds to d in the discount, metres per radian of heading
        change: an edge costs max(its length, this * its turn), the distance the vehicle flies
        in the time the turn takes (IROS Eq. 7's traversal cost c(sigma); the default is the
        simulated vehicle's speed limit over its yaw-rate limit, ControllerConfig's 0.25 m/s over
        0.15 rad/s). 0: turns are free, as in nbvplanner.
    gain_range_m: range of the simulated sensor rays in the gain (d_max^planner).
    gain_step_m: spacing of the simulated scans along an edge; a turn is sampled so that the
        fan moves at most this far at gain_range_m (thesis 4.5.4: the path-segment gain).
    gain_unknown, gain_free, gain_occupied: what one voxel of each state adds to a view's gain,
        in voxel volumes (nbvplanner counts unknown voxels only).
    box_x_m, box_y_m, box_z_m: the collision box (extents, world-aligned), swept along every edge.
    margin_m: the box is grown by this much on every side for collision checks: the vehicle's
        estimate drifts from older parts of the map between loop closures (the papers use none;
        without it the tank's walls get grazed).
    clearance_m: unknown voxels within this distance of the vehicle's position count as free
        (besides those in its own box): a profiling sonar at the bow never sees the water just
        around the vehicle, so without it no edge could leave the vehicle's box. Occupied voxels
        are never free.
    max_heading_change_rad: bound on the heading change between a node and its parent
        (constrained sampling, thesis 4.5.3; 90 degrees in its Fig. 4.14).
    vertical_fraction: share of samples drawn along z at the vehicle's x, y (the rest in the
        x-y plane at the vehicle's depth), thesis 4.5.3.
    min_gain_m3: exploration is done when the best branch gains no more than this (m^3; 0: the
        tree grew to N_tol and found nothing to see, the papers' criterion).
    risk_weight: weight of a collision-risk cost per edge (the planner's `risk` hook, e.g. a
        confidence-rich map's cost): an edge's gain is also multiplied by exp(-risk_weight *
        risk). 0 disables it; > 0 needs a `risk` callable.
    seed: seed of the sampling.
    collision_level, gain_level: the map level the collision checks and the gain rays read: 0
        the map's voxels; k >= 1 voxels of voxel_size * 2^k holding the most occupied of their
        observed voxels (`docs/concepts/multi-resolution.md`). A coarse level never lets an edge
        through an OCCUPIED voxel, but reads a coarse voxel as FREE when its observed voxels
        are, unknown ones among them; a coarse gain counts coarse voxels (their volume), so
        partly seen ones count as seen. Needs a VoxelMap, GlobalMap or VogMap (not an Overlay).
    """

    edge_length_m: float = positive(2.0)
    max_nodes: int = integer(15, low=1, high=MAX_TREE_NODES)
    tolerance_nodes: int = integer(60, low=1, high=MAX_TREE_NODES)
    attempts_per_node: int = integer(8, low=1, high=1000)
    discount: float = non_negative(0.5)
    turn_cost_m_per_rad: float = non_negative(ControllerConfig().max_speed_mps / ControllerConfig().max_yaw_rate_rps)
    gain_range_m: float = positive(5.0)
    gain_step_m: float = positive(0.1)
    gain_unknown: float = non_negative(1.0)
    gain_free: float = non_negative(0.0)
    gain_occupied: float = non_negative(0.0)
    box_x_m: float = positive(1.0)
    box_y_m: float = positive(1.0)
    box_z_m: float = positive(0.5)
    margin_m: float = non_negative(0.25)
    clearance_m: float = non_negative(1.5)
    max_heading_change_rad: float = number(1.5707963267948966, low=0.0, high=3.141592653589793)
    vertical_fraction: float = number(0.25, low=0.0, high=1.0)
    min_gain_m3: float = non_negative(0.0)
    risk_weight: float = non_negative(0.0)
    seed: int = integer(0, low=0)
    collision_level: int = integer(0, low=0, high=15)
    gain_level: int = integer(0, low=0, high=15)

    def check(self) -> None:
        if self.tolerance_nodes < self.max_nodes:
            raise ValueError("PlannerConfig.tolerance_nodes (N_tol) must be at least max_nodes (N_max)")
        if self.gain_unknown + self.gain_free + self.gain_occupied == 0:
            raise ValueError("PlannerConfig: at least one of gain_unknown, gain_free, gain_occupied must be > 0")

    @property
    def box_m(self) -> tuple[float, float, float]:
        return (self.box_x_m, self.box_y_m, self.box_z_m)


@dataclasses.dataclass(frozen=True)
class ExploreConfig(Config):
    """Everything `vogjax explore` reads from its settings file: [planner] sets `planner`; the
    pipeline's tables of `vogjax map` ([map], [nav_noise], [loop_closure] with its .icp and
    .correlative, [timing], [pipeline]) set `pipeline`; [report] is not one of them."""

    pipeline: PipelineConfig = section(PipelineConfig(), flatten=True)
    planner: PlannerConfig = section(PlannerConfig())
