"""Simulation: the MJX vehicle, range scans of the scene, drifting navigation, runs."""

from vogjax.sim.mission import RunSummary, simulate_run
from vogjax.sim.navigation import drifting_navigation
from vogjax.sim.ranging import SimulatedScans, scan
from vogjax.sim.vehicle import simulate, simulate_batch

__all__ = ["RunSummary", "SimulatedScans", "drifting_navigation", "scan", "simulate",
           "simulate_batch", "simulate_run"]
