"""Settings of the simulated vehicle."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, flag, positive


@dataclasses.dataclass(frozen=True)
class ControllerConfig(Config):
    """Settings of the simulated vehicle's waypoint controller; the speed limits are the papers'.

    Attributes
    ----------
    max_speed_mps : float
        Speed limit, m/s (the papers' 0.25 m/s).
    max_yaw_rate_rps : float
        Yaw-rate limit, rad/s (the papers' 0.15 rad/s).
    position_gain : float
        Desired speed per metre of position error, 1/s.
    yaw_gain : float
        Desired yaw rate per radian of heading error, 1/s.
    velocity_gain : float
        Extra thrust per m/s of velocity error, N s/m.
    yaw_rate_gain : float
        Extra torque per rad/s of yaw-rate error, N m s.
    tolerance_m : float
        A waypoint is reached within this distance, metres (and `tolerance_rad`).
    tolerance_rad : float
        A waypoint is reached within this heading error, radians (and `tolerance_m`).
    yaw_along_path : bool
        Fly a waypoint as one motion: position and heading are slowed so that both arrive
        together, the vehicle turning at a steady rate while it translates along the straight
        line (the motion the planner's gain assumes, `vogjax.planner.edge_views`). Off (the
        default, and the papers' surveys): each axis runs at its own limit, so a turn that
        takes longer than the translation ends as a turn in place.
    """

    max_speed_mps: float = positive(0.25)
    max_yaw_rate_rps: float = positive(0.15)
    position_gain: float = positive(0.6)
    yaw_gain: float = positive(0.8)
    velocity_gain: float = positive(300.0)
    yaw_rate_gain: float = positive(120.0)
    tolerance_m: float = positive(0.15)
    tolerance_rad: float = positive(0.05)
    yaw_along_path: bool = flag(False)
