"""Next-best-view exploration: the receding-horizon RRT planner of Bircher et al. with Ho's
changes for a profiling sonar (constrained sampling, gain along edges), on any vogjax map.

    gain = planner.view_gain(map, T_world_sensor, sensor)       # batched view gain
    nbv = planner.NbvPlanner(PlannerConfig(), bounds=scene.bounds, sensor=sonar)
    plan = nbv.plan(map, T_world_vehicle)                       # waypoints, gain, timings
"""

from vogjax.config.planner import PlannerConfig
from vogjax.planner.collision import edges_clear
from vogjax.planner.gain import ViewGain, discounted, edge_gain, edge_views, view_gain
from vogjax.planner.nbv import NbvPlanner, Plan
from vogjax.planner.source import Overlay

__all__ = [
    "NbvPlanner",
    "Overlay",
    "Plan",
    "PlannerConfig",
    "ViewGain",
    "discounted",
    "edge_gain",
    "edge_views",
    "edges_clear",
    "view_gain",
]
