"""Settings of the simulated vehicle."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, flag, positive


@dataclasses.dataclass(frozen=True)
class ControllerConfig(Config):
    """Speed limits of the papers (0.25 m/s, 0.15 rad/s); position_gain: desired speed per
    metre of error, 1/s; yaw_gain: desired yaw rate per radian of error, 1/s; velocity_gain:
    extra thrust per m/s of velocity error, N s/m; yaw_rate_gain: extra torque per rad/s of
    yaw-rate error, N m s; a waypoint is reached within tolerance_m and tolerance_rad.

    yaw_along_path: fly a waypoint as one motion: position and heading are slowed so that both
    arrive together, the vehicle turning at a steady rate while it translates along the
    straight line (the motion the planner's gain assumes, `vogjax.planner.edge_views`). Off
    (the default, and the papers' surveys): each axis runs at its own limit, so a turn that
    takes longer than the translation ends as a turn in place."""

    max_speed_mps: float = positive(0.25)
    max_yaw_rate_rps: float = positive(0.15)
    position_gain: float = positive(0.6)
    yaw_gain: float = positive(0.8)
    velocity_gain: float = positive(300.0)
    yaw_rate_gain: float = positive(120.0)
    tolerance_m: float = positive(0.15)
    tolerance_rad: float = positive(0.05)
    yaw_along_path: bool = flag(False)
