"""Simulation: the MJX vehicle, range scans of the scene, drifting navigation, runs.

Names are imported on first use, so the Warp ray casts (`vogjax.sim.ranging`, `scan`) work
without loading MuJoCo and JAX."""

import importlib

_HOMES = {
    "RunSummary": "mission",
    "simulate_run": "mission",
    "drifting_navigation": "navigation",
    "SimulatedScans": "ranging",
    "simulate_lidar_run": "lidar_mission",
    "scan": "ranging",
    "simulate": "vehicle",
    "simulate_batch": "vehicle",
}

__all__ = [
    "RunSummary",
    "SimulatedScans",
    "drifting_navigation",
    "scan",
    "simulate",
    "simulate_batch",
    "simulate_lidar_run",
    "simulate_run",
]


def __getattr__(name):
    if name in _HOMES:
        return getattr(importlib.import_module(f"vogjax.sim.{_HOMES[name]}"), name)
    raise AttributeError(f"module 'vogjax.sim' has no attribute {name!r}")
