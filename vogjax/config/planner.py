"""Settings of the next-best-view planner (`vogjax.planner.NbvPlanner`).

Defaults are Ho's propeller experiment (thesis Table 4.2, IROS Table I) for the tree: 2 m RRT
edges, N_max = 15, lambda = 0.5 and a 1.0 x 1.0 x 0.5 m collision box (with the papers' 5 m
planner range in PAPERS); for the tank (thesis Table 4.4) the papers used edge_length_m = 1.0,
gain_range_m = 5.63, discount = 0 (`vogjax.sim.explore.scene_planner(..., rule="papers")`).

How a branch is chosen and flown defaults to the time-aware rule (an edge costs the time to
fly it, the best branch gains the most per second, the vehicle turns while it translates);
`PAPERS` holds the settings that select the papers' rule instead (gain discounted by path
length, each axis flown at its own limit, their checks and sampling), for reproducing their
figures.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from vogjax.config.maps import MapConfig
from vogjax.config.pipeline import PipelineConfig
from vogjax.config.schema import Config, flag, integer, non_negative, number, positive, rule_of, section, text
from vogjax.config.sim import ControllerConfig

# The most nodes a tree may grow to: each round finds its samples' nearest nodes among all of
# them, and the work grows with the square of the tree (the papers use N_tol of 60 or so).
MAX_TREE_NODES = 10_000
SELECTIONS = ("gain_rate", "discounted")
GAINS = ("volume", "frontier")
GAIN_REGIONS = ("bounds", "scene")


@dataclasses.dataclass(frozen=True)
class PlannerConfig(Config):
    """Settings of the next-best-view planner: the tree, the gain, the collision checks and the rule.

    Defaults are the papers' tree (thesis Table 4.2) under the time-aware rule; `PAPERS` selects
    the papers' rule. A grouped description (gain_unknown, gain_free, gain_occupied; the speed
    limits; the levels) is repeated for each of its settings.

    Attributes
    ----------
    edge_length_m : float
        Longest RRT edge (the extension range), metres.
    max_nodes : int
        N_max, nodes the tree grows to when its best branch gains something.
    tolerance_nodes : int
        N_tol, nodes it may grow to while the best gain stays zero.
    attempts_per_node : int
        Samples allowed per wanted node before giving up (collisions reject many).
    discount : float
        Lambda of the gain formula: an edge's gain counts exp(-lambda * d), d the traversal cost from the
        vehicle to the edge's end along the branch, metres (nbvplanner's discount; turns count through
        turn_cost_m_per_rad).
    turn_cost_m_per_rad : float
        What a turn adds to d in the discount, metres per radian of heading change: an edge costs max(its
        length, this * its turn), the distance the vehicle flies in the time the turn takes (IROS Eq. 7's
        traversal cost c(sigma); the default is the simulated vehicle's speed limit over its yaw-rate limit,
        ControllerConfig's 0.25 m/s over 0.15 rad/s). 0: turns are free, as in nbvplanner.
    gain_range_m : float
        Range of the simulated sensor rays in the gain (d_max^planner): 8 m by default, most of the papers'
        sonar's 11 m reach (what the fan will see: with 5 m the planner counted a fifth of what its flights
        revealed); 5 m in PAPERS (Table 4.2).
    gain_step_m : float
        Spacing of the simulated scans along an edge; a turn is sampled so that the fan moves at most this far
        at gain_range_m (thesis 4.5.4: the path-segment gain). 0.2 m by default, 0.1 m in PAPERS.
    min_edge_length_m : float
        An edge shorter than this is not grown (the controller reaches a waypoint within 0.15 m: a shorter
        edge is no motion at all, and its stop costs a plan); 0 in PAPERS.
    gain_unknown : float
        What one voxel of each state adds to a view's gain, in voxel volumes (nbvplanner counts unknown voxels
        only).
    gain_free : float
        What one voxel of each state adds to a view's gain, in voxel volumes (nbvplanner counts unknown voxels
        only).
    gain_occupied : float
        What one voxel of each state adds to a view's gain, in voxel volumes (nbvplanner counts unknown voxels
        only).
    box_x_m : float
        The collision box (extents, world-aligned), swept along every edge.
    box_y_m : float
        The collision box (extents, world-aligned), swept along every edge.
    box_z_m : float
        The collision box (extents, world-aligned), swept along every edge.
    margin_m : float
        The box is grown by this much on every side in x and y for collision checks: the vehicle's estimate
        drifts from older parts of the map between loop closures (the papers use none; without it the tank's
        walls get grazed).
    margin_z_m : float
        The same above and below: depth is measured, not dead-reckoned (0.1 m by default, 0.25 m in PAPERS, as
        in x-y). The box's top is what a climb must have seen.
    obstacle_margin_m : float
        Occupied voxels are kept this much farther off in x and y than unknown ones (a box grown by it as
        well, swept for them alone): drift misplaces the obstacles the map holds, and under the default
        navigation noise (a sigma of 0.4 m after 100 s) margin_m alone let the box graze the tank's ladder and
        a piling; unknown water is no nearer for drift, and a wider box for it would leave the vehicle no edge
        out of its blind ring. 0 in PAPERS.
    drift_margin_sigmas : float
        Occupied voxels are kept this many sigmas of the navigation's drift farther off again, the sigma
        passed to each plan (`vogjax explore`: the x-y drift the navigation noise accrues since the last
        submap a loop closure anchored; 0 in PAPERS), at most max_drift_margin_m.
    max_drift_margin_m : float
        The cap of that drift margin, metres (a wider one leaves no way between the pilings).
    clearance_m : float
        Unknown voxels within this distance of the vehicle's position count as free (besides those in its own
        box): a profiling sonar at the bow never sees the water just around the vehicle, so without it no edge
        could leave the vehicle's box. Occupied voxels are never free.
    blind_vertical : bool
        The clearance frees unknown water above and below the vehicle's box as well, so a climb may enter
        water no beam has crossed (the papers' check). Off (default): only in the layer of the vehicle's box;
        a climb or descent enters water seen free.
    sloped_fraction : float
        Share of the x-y samples that also climb or descend, at most as steeply as the sensor's beams look up
        or down (4.5 degrees up, 24.5 down for the papers' sonar), so that the layer the vehicle travels in
        stays one its fan has seen (climbing in steps into space seen free); the rest stay at their parent's
        depth. 0: none (the papers').
    global_step : bool
        When the local tree's best score falls to global_below or less, `vogjax explore` takes a global step:
        a trip over the explored graph (every tree so far) to the vertex with the most gain per second of the
        trip (GBPlanner's repositioning), instead of a local edge, or of stopping when nothing local gains
        anything. Off in PAPERS.
    global_below : float
        The local score at or below which a global step is tried (m^3 per second for "gain_rate", m^3 for
        "discounted").
    min_round_samples : int
        Samples drawn per round of tree growth at least (a round is one launch of collision checks and one of
        gains; where most samples collide, rounds of one cost a launch each). 1 in PAPERS (their trees grow 1,
        1, 2, 3, ... samples a round).
    max_heading_change_rad : float
        Bound on the heading change between a node and its parent (constrained sampling, thesis 4.5.3; 90
        degrees in its Fig. 4.14).
    vertical_fraction : float
        Share of samples drawn along z at the vehicle's x, y (the rest in the x-y plane at the vehicle's
        depth), thesis 4.5.3: 0.25 in PAPERS, 0.1 by default (a climb straight up needs water seen free above
        the vehicle, which a forward fan sees only from afar, so most such samples collide; the sloped ones
        climb instead).
    min_gain_m3 : float
        Exploration is done when the best branch gains no more than this (m^3; 0: the tree grew to N_tol and
        found nothing to see, the papers' criterion).
    risk_weight : float
        Weight of a collision-risk cost per edge (the planner's `risk` hook, e.g. a confidence-rich map's
        cost): an edge's gain is also multiplied by exp(-risk_weight * risk). 0 disables it; > 0 needs a
        `risk` callable.
    seed : int
        Seed of the sampling.
    selection : str
        How the best branch is chosen. "gain_rate" (default): the most gain per second of flight, an edge
        taking max(length / max_speed_mps, turn / max_yaw_rate_rps) plus edge_overhead_s (FUEL's time cost,
        with the stop at each waypoint); "discounted": the papers' rule, the most gain discounted by
        exp(-discount * d) (see discount).
    max_speed_mps : float
        The vehicle's limits the edge times assume (default the simulated vehicle's, ControllerConfig).
    max_yaw_rate_rps : float
        The vehicle's limits the edge times assume (default the simulated vehicle's, ControllerConfig).
    edge_overhead_s : float
        Seconds an edge costs beyond its time at the limits: the vehicle slows into each waypoint and the
        planner plans there (about 1 s for the simulated controller).
    yaw_along_path : bool
        Yaw is planned along the path: an edge turns at most as far as the yaw-rate limit allows while its
        translation is flown (max_yaw_rate_rps * length / max_speed_mps), and the vehicle turns while it
        translates, reaching the node's heading as it reaches its position (the motion the edge's gain views
        assume). Off: headings are sampled within max_heading_change_rad whatever the edge's length, and each
        axis runs at its own limit (the papers' flight, where a long turn ends in place).
    initial_turn_rad : float
        The turn in place before the first plan (nbvplanner's initial motion: a full turn, so that the first
        tree has a map to grow in), radians; 0: none.
    gain : str
        What an edge's views count. "volume": voxels by state, weighted by gain_unknown, gain_free and
        gain_occupied (nbvplanner's volumetric gain); "frontier": the unknown voxels with a FREE face
        neighbour, on the boundary of the water already measured (FUEL's frontier cells): none lies behind a
        surface no beam has crossed.
    gain_region : str
        Where gain counts (`vogjax explore`): "bounds", the scene's exploration box (the volume to explore);
        "scene", the box holding the scene's mesh and that box (the papers' runs counted everything the rays
        reach).
    collision_level : int
        The map level the collision checks read: 0 the map's voxels; k >= 1 voxels of voxel_size * 2^k
        holding the most occupied of their observed voxels (`docs/concepts/multi-resolution.md`). A coarse
        level never lets an edge through an OCCUPIED voxel, but reads a coarse voxel as FREE when its observed
        voxels are, unknown ones among them. Needs a VoxelMap, GlobalMap or VogMap (not an Overlay).
    gain_level : int
        The map level the gain rays read, as `collision_level`: a coarse gain counts coarse voxels (their
        volume), so partly seen ones count as seen.

    Raises
    ------
    ValueError
        If a setting is out of its range, tolerance_nodes is below max_nodes, or every gain
        weight is 0.
    """

    edge_length_m: float = positive(2.0)
    max_nodes: int = integer(15, low=1, high=MAX_TREE_NODES)
    tolerance_nodes: int = integer(60, low=1, high=MAX_TREE_NODES)
    attempts_per_node: int = integer(8, low=1, high=1000)
    discount: float = non_negative(0.5)
    turn_cost_m_per_rad: float = non_negative(ControllerConfig().max_speed_mps / ControllerConfig().max_yaw_rate_rps)
    gain_range_m: float = positive(8.0)
    gain_step_m: float = positive(0.2)
    gain_unknown: float = non_negative(1.0)
    gain_free: float = non_negative(0.0)
    gain_occupied: float = non_negative(0.0)
    box_x_m: float = positive(1.0)
    box_y_m: float = positive(1.0)
    box_z_m: float = positive(0.5)
    margin_m: float = non_negative(0.25)
    margin_z_m: float = non_negative(0.1)
    obstacle_margin_m: float = non_negative(0.15)
    drift_margin_sigmas: float = non_negative(1.0)
    max_drift_margin_m: float = non_negative(0.45)
    clearance_m: float = non_negative(1.5)
    max_heading_change_rad: float = number(1.5707963267948966, low=0.0, high=3.141592653589793)
    vertical_fraction: float = number(0.1, low=0.0, high=1.0)
    min_gain_m3: float = non_negative(0.0)
    risk_weight: float = non_negative(0.0)
    seed: int = integer(0, low=0)
    selection: str = text("gain_rate", SELECTIONS)
    max_speed_mps: float = positive(ControllerConfig().max_speed_mps)
    max_yaw_rate_rps: float = positive(ControllerConfig().max_yaw_rate_rps)
    edge_overhead_s: float = non_negative(1.0)
    yaw_along_path: bool = flag(True)
    gain: str = text("volume", GAINS)
    gain_region: str = text("scene", GAIN_REGIONS)
    initial_turn_rad: float = number(6.283185307179586, low=0.0, high=6.283185307179586)
    blind_vertical: bool = flag(False)
    sloped_fraction: float = number(0.5, low=0.0, high=1.0)
    global_step: bool = flag(True)
    global_below: float = non_negative(0.1)
    min_round_samples: int = integer(8, low=1, high=MAX_TREE_NODES)
    min_edge_length_m: float = non_negative(0.3)
    collision_level: int = integer(0, low=0, high=15)
    gain_level: int = integer(0, low=0, high=15)

    def check(self) -> None:
        if self.tolerance_nodes < self.max_nodes:
            raise ValueError("PlannerConfig.tolerance_nodes (N_tol) must be at least max_nodes (N_max)")
        if self.gain_unknown + self.gain_free + self.gain_occupied == 0:
            raise ValueError("PlannerConfig: at least one of gain_unknown, gain_free, gain_occupied must be > 0")

    @property
    def box_m(self) -> tuple[float, float, float]:
        """The collision box's extents (box_x_m, box_y_m, box_z_m), metres."""
        return (self.box_x_m, self.box_y_m, self.box_z_m)

    @property
    def checked_box_m(self) -> tuple[float, float, float]:
        """The box the collision checks sweep: box_m grown by margin_m in x-y, margin_z_m in z."""
        return (self.box_x_m + 2 * self.margin_m, self.box_y_m + 2 * self.margin_m, self.box_z_m + 2 * self.margin_z_m)

    def obstacle_margins_m(self, drift_m: float = 0.0) -> tuple[float, float, float]:
        """How much farther occupied voxels are kept than unknown ones, per axis.

        Parameters
        ----------
        drift_m : float, optional
            How far (one sigma, x-y, metres) the vehicle's estimate may have drifted from where
            the map put what it holds.

        Returns
        -------
        tuple of float
            (x, y, z) margins, metres: obstacle_margin_m plus drift_margin_sigmas * drift_m (at
            most max_drift_margin_m) in x and y, 0 in z (depth is measured).
        """
        margin = self.obstacle_margin_m + min(self.drift_margin_sigmas * drift_m, self.max_drift_margin_m)
        return (margin, margin, 0.0)

    def edge_seconds(self, length_m: npt.ArrayLike, turn_rad: npt.ArrayLike) -> float | npt.NDArray[np.float64]:
        """Seconds to fly edges under the vehicle's limits (FUEL's edge time, plus the stop).

        Parameters
        ----------
        length_m : float or array_like of float
            Each edge's length, metres.
        turn_rad : float or array_like of float
            Each edge's heading change, radians (either sign); broadcast against length_m.

        Returns
        -------
        float or ndarray of float64
            max(length / max_speed_mps, abs(turn) / max_yaw_rate_rps) + edge_overhead_s: a float
            for floats, an array for arrays.
        """
        return (
            np.maximum(np.abs(length_m) / self.max_speed_mps, np.abs(turn_rad) / self.max_yaw_rate_rps)
            + self.edge_overhead_s
        )


# The settings that select the papers' rule (with the tree settings of PlannerConfig's
# defaults or `scene_planner`'s): `PlannerConfig(**PAPERS)` reproduces their figures.
PAPERS = {
    "selection": "discounted",
    "yaw_along_path": False,
    "gain": "volume",
    "gain_region": "scene",
    "margin_m": 0.25,
    "margin_z_m": 0.25,
    "obstacle_margin_m": 0.0,
    "drift_margin_sigmas": 0.0,
    "blind_vertical": True,
    "sloped_fraction": 0.0,
    "global_step": False,
    "min_round_samples": 1,
    "vertical_fraction": 0.25,
    "gain_range_m": 5.0,
    "gain_step_m": 0.1,
    "min_edge_length_m": 0.0,
}


@dataclasses.dataclass(frozen=True)
class ExploreConfig(Config):
    """Everything `vogjax explore` reads from its settings file: [planner] sets `planner`; the
    pipeline's tables of `vogjax map` ([map], [nav_noise], [loop_closure] with its .icp and
    .correlative, [timing], [pipeline]) set `pipeline`; [report] is not one of them."""

    pipeline: PipelineConfig = section(PipelineConfig(), flatten=True)
    planner: PlannerConfig = section(PlannerConfig())

    def check(self) -> None:
        # what `vogjax explore` would otherwise refuse only once it plans, after the first submaps
        if self.planner.risk_weight > 0:
            raise ValueError(
                "planner.risk_weight > 0 needs a risk callable (NbvPlanner(risk=...) in Python); "
                "`vogjax explore` has none: leave it at 0"
            )
        # a map level of voxel_size * 2^k is read as a map of that voxel size: MapConfig's bound
        largest_m = rule_of(next(f for f in dataclasses.fields(MapConfig) if f.name == "voxel_size")).high
        voxel_m = self.pipeline.map.voxel_size
        for name in ("collision_level", "gain_level"):
            level = getattr(self.planner, name)
            if voxel_m * 2**level > largest_m:
                raise ValueError(
                    f"planner.{name} = {level}: voxels of {voxel_m * 2**level:g} m at map.voxel_size "
                    f"{voxel_m:g} m, past the {largest_m:g} m a map level may have"
                )
