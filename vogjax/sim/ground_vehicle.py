"""A ground vehicle driving a route on a flat floor, and the wheel odometry it dead-reckons with.

The route is the polyline from the start through the waypoints' x, y, its corners rounded by
circular arcs of `turn_radius_m`; the vehicle drives it at `speed_mps`, speeding up from rest
and slowing to a stop at `accel_mps2`, heading along the path (yaw rate speed / radius in a
turn). The pose is a closed-form function of time (`poses`), so a spinning lidar's every column
is cast from where the vehicle truly was when it fired. The floor is not perfectly level: the
base pitches and rolls by a few tenths of a degree as it drives.

The wheel odometry a run records (`vogjax.config.presets.WHEEL_ODOMETRY`, drifted by
`vogjax.sim.navigation.drifting_navigation` at `ODOMETRY_RATE_HZ`) is Sodhi et al.'s Eq. 10
drift with a ground vehicle's figures: x, y and yaw noise on every step accumulate (wheel slip:
the heading random-walks at 0.18 degrees per square-root second, 100 times the HAUV gyro's
variance), while z, pitch and roll stay tied to the truth (the floor and an inclinometer
measure them absolutely).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from vogjax.config.schema import Rule
from vogjax.geometry import rigid_pose, rotation_from_ypr
from vogjax.validation import float_array

ODOMETRY_RATE_HZ = 100.0  # wheel encoders' rate: the deskewing interpolates between these
# The floor's unevenness: pitch and roll amplitudes (rad) and frequencies (Hz) while driving.
WOBBLE = ((0.003, 0.7), (0.002, 1.1))
MAX_DURATION_S = 1e6


@dataclasses.dataclass(frozen=True)
class _Piece:
    """A straight piece (radius 0) or an arc of the route, from arc length `start_m`."""

    start_m: float
    length_m: float
    x: float
    y: float
    heading: float
    curvature: float  # 1 / radius, signed (positive: turning left); 0 on a straight


class GroundVehicle:
    """A vehicle driving a route of straights and rounded corners at a set speed.

    Parameters
    ----------
    start_pose : (4, 4) array_like of float
        ``T_world_vehicle`` at rest at the start (its x, y, z and yaw are used).
    waypoints : (W, 4) array_like of float
        x, y (metres) the route passes through in order, then z and yaw (ignored: the vehicle
        stays on the start's floor height and heads along its path); W >= 1.
    speed_mps : float, optional
        Cruising speed, metres per second.
    turn_radius_m : float, optional
        Radius of the arcs that round the corners, metres.
    accel_mps2 : float, optional
        Acceleration from rest and deceleration to the stop, metres per second squared.

    Attributes
    ----------
    length_m : float
        Length of the route, metres.
    duration_s : float
        Time from the start to the stop, seconds.

    Raises
    ------
    ValueError
        If an argument is malformed, two waypoints coincide, or a corner's legs are too short
        for its arc.
    """

    def __init__(
        self,
        start_pose: npt.ArrayLike,
        waypoints: npt.ArrayLike,
        speed_mps: float = 2.0,
        turn_radius_m: float = 4.0,
        accel_mps2: float = 0.5,
    ):
        start = rigid_pose("start_pose", start_pose)
        points = float_array("waypoints", waypoints, (-1, 4), np.float64)
        if len(points) == 0:
            raise ValueError("waypoints must hold at least one waypoint")
        for name, value in (("speed_mps", speed_mps), ("turn_radius_m", turn_radius_m), ("accel_mps2", accel_mps2)):
            Rule("number", 0, low_open=True).check(name, value)
        self.speed_mps, self.accel_mps2 = float(speed_mps), float(accel_mps2)
        self.z_m = float(start[2, 3])
        polyline = np.vstack([start[:2, 3], points[:, :2]])
        legs = np.diff(polyline, axis=0)
        lengths = np.linalg.norm(legs, axis=1)
        if np.any(lengths < 1e-6):
            raise ValueError("waypoints must not repeat a point (or the start) twice in a row")
        headings = np.arctan2(legs[:, 1], legs[:, 0])
        self._pieces: list[_Piece] = []
        s, position = 0.0, polyline[0].copy()
        trimmed_start = 0.0  # of the current leg, taken by the previous corner's arc
        for leg in range(len(legs)):
            turn = 0.0 if leg == len(legs) - 1 else _wrap(headings[leg + 1] - headings[leg])
            cut = turn_radius_m * np.tan(abs(turn) / 2)
            straight = lengths[leg] - trimmed_start - cut
            if straight < -1e-9:
                raise ValueError(
                    f"waypoints: leg {leg} ({lengths[leg]:.3g} m) is too short for the arcs of turn_radius_m "
                    f"{turn_radius_m:g} that round its corners (use a smaller radius or longer legs)"
                )
            straight = max(straight, 0.0)
            self._pieces.append(_Piece(s, straight, position[0], position[1], headings[leg], 0.0))
            s += straight
            position = position + straight * np.array([np.cos(headings[leg]), np.sin(headings[leg])])
            if abs(turn) > 1e-12:
                arc = turn_radius_m * abs(turn)
                curvature = np.sign(turn) / turn_radius_m
                self._pieces.append(_Piece(s, arc, position[0], position[1], headings[leg], curvature))
                s += arc
                position = self._along(self._pieces[-1], arc)[:2]
            trimmed_start = cut
        self.length_m = s
        self._starts = np.array([p.start_m for p in self._pieces])
        # trapezoidal speed: up to speed, cruise, down to rest (a triangle on a short route)
        ramp_m = self.speed_mps**2 / (2 * self.accel_mps2)
        if 2 * ramp_m > s:
            self._peak = np.sqrt(s * self.accel_mps2)
            self._ramp_s, self._cruise_s = self._peak / self.accel_mps2, 0.0
        else:
            self._peak = self.speed_mps
            self._ramp_s, self._cruise_s = self.speed_mps / self.accel_mps2, (s - 2 * ramp_m) / self.speed_mps
        self.duration_s = 2 * self._ramp_s + self._cruise_s
        if not self.duration_s <= MAX_DURATION_S:
            raise ValueError(f"the route takes {self.duration_s:.3g} s, more than {MAX_DURATION_S:g} s")

    @staticmethod
    def _along(piece: _Piece, d: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(x, y, heading) at distances d into a piece, (..., 3)."""
        d = np.asarray(d, dtype=np.float64)
        if piece.curvature == 0.0:
            x, y = piece.x + d * np.cos(piece.heading), piece.y + d * np.sin(piece.heading)
            return np.stack([x, y, np.full_like(d, piece.heading)], axis=-1)
        k = piece.curvature
        heading = piece.heading + k * d
        x = piece.x + (np.sin(heading) - np.sin(piece.heading)) / k
        y = piece.y - (np.cos(heading) - np.cos(piece.heading)) / k
        return np.stack([x, y, heading], axis=-1)

    def distance_m(self, times_s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Distance driven by each time (0 before the start, the route's length after the stop).

        Parameters
        ----------
        times_s : (N,) array_like of float
            Seconds since the start.

        Returns
        -------
        (N,) ndarray of float64
            Metres along the route.
        """
        t = np.clip(np.asarray(times_s, dtype=np.float64), 0.0, self.duration_s)
        a, ramp, cruise = self.accel_mps2, self._ramp_s, self._cruise_s
        ramp_m = 0.5 * a * ramp**2
        out = np.where(t <= ramp, 0.5 * a * t**2, ramp_m + self._peak * (t - ramp))
        late = t > ramp + cruise
        left = self.duration_s - t
        return np.where(late, self.length_m - 0.5 * a * left**2, out)

    def poses(self, times_s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The vehicle's true poses at given times.

        Parameters
        ----------
        times_s : (N,) array_like of float
            Seconds since the start (any order; clamped to [0, duration_s]).

        Returns
        -------
        (N, 4, 4) ndarray of float64
            ``T_world_vehicle``: on the route, heading along it, z at the start's, pitching and
            rolling with the floor (`WOBBLE`) while it moves.
        """
        t = np.asarray(times_s, dtype=np.float64).reshape(-1)
        s = self.distance_m(t)
        index = np.clip(np.searchsorted(self._starts, s, side="right") - 1, 0, len(self._pieces) - 1)
        xyh = np.empty((len(t), 3))
        for k in np.unique(index):
            rows = index == k
            piece = self._pieces[k]
            xyh[rows] = self._along(piece, np.minimum(s[rows] - piece.start_m, piece.length_m))
        moving = np.clip(s / 1.0, 0.0, 1.0) * np.clip((self.length_m - s) / 1.0, 0.0, 1.0)  # level at rest
        (pitch_amp, pitch_hz), (roll_amp, roll_hz) = WOBBLE
        pitch = moving * pitch_amp * np.sin(2 * np.pi * pitch_hz * t)
        roll = moving * roll_amp * np.sin(2 * np.pi * roll_hz * t + 1.0)
        out = np.zeros((len(t), 4, 4))
        out[:, :3, :3] = rotation_from_ypr(xyh[:, 2], pitch, roll)
        out[:, 0, 3], out[:, 1, 3], out[:, 2, 3] = xyh[:, 0], xyh[:, 1], self.z_m
        out[:, 3, 3] = 1.0
        return out


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)
