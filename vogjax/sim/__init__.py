"""Simulation: the MJX vehicle, the profiling sonar, drifting navigation, survey patterns, runs."""

from vogjax.sim.mission import RunSummary, simulate_run
from vogjax.sim.navigation import drifting_navigation
from vogjax.sim.sonar import SonarScans, beam_directions, scan
from vogjax.sim.trajectories import lawnmower, mission, orbit
from vogjax.sim.vehicle import ControllerConfig, simulate, simulate_batch

__all__ = ["ControllerConfig", "RunSummary", "SonarScans", "beam_directions", "drifting_navigation",
           "lawnmower", "mission", "orbit", "scan", "simulate", "simulate_batch", "simulate_run"]
