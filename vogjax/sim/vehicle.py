"""The vehicle: MJX physics of the AUV model and a waypoint controller, in JAX.

`simulate` steps the model with `jax.jit` of `mjx.step` under `lax.scan`; `simulate_batch`
runs many vehicles at once with `vmap`. The controller asks for velocities within the papers'
limits (0.25 m/s, 0.15 rad/s) and turns them into thrust.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import numpy.typing as npt
from mujoco import mjx

from vogjax.config import ControllerConfig
from vogjax.config.schema import Rule
from vogjax.geometry import (
    quaternions_from_rotations,
    rigid_pose,
    rigid_poses,
    rotation_from_quaternion,
    rotations_from_quaternions,
    wrap_angle,
    yaw_of_quaternion,
)
from vogjax.sim.vehicle_model import HAUV_XML
from vogjax.validation import float_array

DAMPING = 150.0  # the model's joint damping: thrust needed per m/s (and per rad/s)
MAX_SCANS = 10_000_000  # 23 days of scans at 5 Hz (the poses alone: 1.3 GB)
MAX_STEPS = 4 * MAX_SCANS  # physics steps of one flight: the same 23 days
# MJX computes in float32: 1e5 m from the origin still resolves 8 mm, well inside a waypoint's
# 0.15 m tolerance; much farther the controller's distances lose the vehicle.
MAX_COORDINATE_M = 1e5
# Scan intervals must be whole numbers of physics steps to this relative tolerance (20/3 Hz,
# as a float, is 3 steps to 1e-16).
STEP_TOLERANCE = 1e-6


@functools.cache
def model() -> tuple[mujoco.MjModel, mjx.Model]:
    host = mujoco.MjModel.from_xml_string(HAUV_XML)
    return host, mjx.put_model(host)


def control(qpos, qvel, target, config: ControllerConfig):
    """Thrusts (surge, sway, heave, yaw) steering toward target (x, y, z, yaw).

    Each axis asks for its proportional rate within its limit; with `config.yaw_along_path`
    both are scaled down to the slower one's time to go, so the vehicle turns while it
    translates and reaches the position and the heading together."""
    error = target[:3] - qpos[:3]
    distance = jnp.linalg.norm(error)
    speed = jnp.minimum(config.position_gain * distance, config.max_speed_mps)
    turn = wrap_angle(target[3] - yaw_of_quaternion(qpos[3:7], jnp))
    yaw_rate = jnp.clip(config.yaw_gain * turn, -config.max_yaw_rate_rps, config.max_yaw_rate_rps)
    if config.yaw_along_path:  # static: the config is a compile-time argument
        translate_s = jnp.where(distance > 1e-9, distance / jnp.maximum(speed, 1e-9), 0.0)
        turn_s = jnp.where(jnp.abs(turn) > 1e-9, turn / jnp.where(yaw_rate == 0.0, 1.0, yaw_rate), 0.0)
        total_s = jnp.maximum(jnp.maximum(translate_s, turn_s), 1e-9)
        speed = jnp.where(translate_s > 0.0, speed * translate_s / total_s, 0.0)
        yaw_rate = jnp.where(turn_s > 0.0, yaw_rate * turn_s / total_s, 0.0)
    velocity = jnp.where(distance > 1e-9, error / jnp.maximum(distance, 1e-9) * speed, 0.0)
    force_world = DAMPING * velocity + config.velocity_gain * (velocity - qvel[:3])
    force_body = rotation_from_quaternion(qpos[3:7], jnp).T @ force_world
    torque = DAMPING * yaw_rate + config.yaw_rate_gain * (yaw_rate - qvel[5])
    return jnp.concatenate([force_body, torque[None]])


def _reached(qpos, target, config: ControllerConfig):
    return (jnp.linalg.norm(target[:3] - qpos[:3]) < config.tolerance_m) & (
        jnp.abs(wrap_angle(target[3] - yaw_of_quaternion(qpos[3:7], jnp))) < config.tolerance_rad
    )


@functools.partial(jax.jit, static_argnames=("num_scans", "steps_per_scan", "config"))
def _run(mx, qpos0, waypoints, num_scans: int, steps_per_scan: int, config: ControllerConfig):
    data = mjx.make_data(mx).replace(qpos=qpos0)

    def physics_step(carry, _):
        data, index = carry
        target = waypoints[index]
        data = mjx.step(mx, data.replace(ctrl=control(data.qpos, data.qvel, target, config)))
        index = jnp.where(_reached(data.qpos, target, config), jnp.minimum(index + 1, len(waypoints) - 1), index)
        return (data, index), None

    def scan_step(carry, _):
        carry, _ = jax.lax.scan(physics_step, carry, None, length=steps_per_scan)
        data, index = carry
        return carry, (data.qpos, index)

    _, (qpos, index) = jax.lax.scan(scan_step, (data, jnp.int32(0)), None, length=num_scans)
    return qpos, index


def _qpos(poses: np.ndarray) -> np.ndarray:
    """(...,4,4) poses -> (...,7) MuJoCo free-joint positions (x, y, z, quaternion w, x, y, z)."""
    poses = np.asarray(poses, dtype=np.float64)
    return np.concatenate([poses[..., :3, 3], quaternions_from_rotations(poses[..., :3, :3])], axis=-1)


def poses_from_qpos(qpos: np.ndarray) -> np.ndarray:
    """(...,7) MuJoCo free-joint positions -> (...,4,4) poses."""
    qpos = np.asarray(qpos, dtype=np.float64)
    out = np.zeros((*qpos.shape[:-1], 4, 4))
    out[..., :3, :3] = rotations_from_quaternions(qpos[..., 3:])
    out[..., :3, 3] = qpos[..., :3]
    out[..., 3, 3] = 1.0
    return out


def steps_per_scan(rate_hz: float, name: str = "scan_rate_hz") -> int:
    """Physics steps between scans at `rate_hz`. Scans are taken only after whole steps, so a
    rate whose interval is not a whole number of steps (to STEP_TOLERANCE) is refused rather
    than rounded: the scan times a run records (scan k at k / rate_hz) are then the simulated
    ones. With the 0.05 s step: 20/n Hz (20, 10, 6.67, 5, 4, ... Hz)."""
    Rule("number", 0, low_open=True).check(name, rate_hz)
    timestep = model()[0].opt.timestep
    if rate_hz * timestep * MAX_STEPS < 1:
        raise ValueError(f"{name} must be at least {1 / (MAX_STEPS * timestep):g} Hz, got {rate_hz!r}")
    steps = 1.0 / (rate_hz * timestep)
    whole = round(steps)
    if whole < 1 or abs(steps - whole) > STEP_TOLERANCE * whole:
        raise ValueError(
            f"{name} must be {1 / timestep:g}/n Hz for a whole number n of {timestep:g} s physics "
            f"steps between scans (20, 10, 6.667, 5, 4, ... Hz), got {rate_hz!r}"
        )
    return int(whole)


def _flight_args(num_scans, scan_rate_hz, config) -> int:
    """Steps per scan, after checking the arguments every flight shares."""
    Rule("integer", 0, MAX_SCANS).check("num_scans", num_scans)
    steps = steps_per_scan(scan_rate_hz)
    if num_scans * steps > MAX_STEPS:
        raise ValueError(
            f"num_scans {num_scans} at {scan_rate_hz:g} Hz is {num_scans * steps} physics steps, "
            f"more than the limit of {MAX_STEPS}"
        )
    if not isinstance(config, ControllerConfig):
        raise ValueError(f"config must be a ControllerConfig, got {type(config).__name__}")
    return steps


def _waypoints(value, shape: tuple) -> np.ndarray:
    waypoints = float_array("waypoints", value, shape, np.float64)
    if waypoints.shape[-2] == 0:
        raise ValueError("waypoints must hold at least one waypoint")
    if np.abs(waypoints[..., :3]).max(initial=0.0) > MAX_COORDINATE_M:
        raise ValueError(f"waypoints must lie within {MAX_COORDINATE_M:g} m of the origin on each axis")
    return waypoints


def _start_poses(name: str, value) -> np.ndarray:
    poses = rigid_poses(name, value)
    if not len(poses):
        raise ValueError(f"{name} must hold at least one pose")
    if np.abs(poses[:, :3, 3]).max(initial=0.0) > MAX_COORDINATE_M:
        raise ValueError(f"{name} must lie within {MAX_COORDINATE_M:g} m of the origin on each axis")
    return poses


def simulate(
    start_pose: npt.ArrayLike,
    waypoints: npt.ArrayLike,
    num_scans: int,
    scan_rate_hz: float = 5.0,
    config: ControllerConfig = ControllerConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """Fly the vehicle in MJX from a start pose through waypoints, recording its pose at each scan.

    Parameters
    ----------
    start_pose : (4, 4) array_like of float
        The vehicle's rigid start pose, world frame.
    waypoints : (W, 4) array_like of float
        x, y, z (m) and yaw (rad) of each waypoint, W >= 1, flown in order.
    num_scans : int
        Scans to record.
    scan_rate_hz : float, optional
        Scans a second; it must give a whole number of physics steps between scans
        (`steps_per_scan`), so scan k is at k / rate.
    config : ControllerConfig, optional
        The waypoint controller's settings.

    Returns
    -------
    poses : (num_scans, 4, 4) ndarray of float64
        The vehicle's pose at each scan.
    index : (num_scans,) ndarray of int
        The waypoint being flown to at each scan.

    Raises
    ------
    ValueError
        If the start pose is not rigid, the waypoints are not finite (W, 4), or `num_scans` or
        `scan_rate_hz` is out of range.
    """
    start_pose = _start_poses("start_pose", rigid_pose("start_pose", start_pose))[0]  # (4,4) only
    waypoints = _waypoints(waypoints, (-1, 4))
    steps = _flight_args(num_scans, scan_rate_hz, config)
    _, mx = model()
    qpos, index = _run(
        mx, jnp.asarray(_qpos(start_pose)), jnp.asarray(waypoints, dtype=jnp.float32), int(num_scans), steps, config
    )
    return poses_from_qpos(np.asarray(qpos)), np.asarray(index)


def simulate_batch(
    start_poses: npt.ArrayLike,
    waypoints: npt.ArrayLike,
    num_scans: int,
    scan_rate_hz: float = 5.0,
    config: ControllerConfig = ControllerConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """`simulate` for V vehicles at once (vmap).

    Parameters
    ----------
    start_poses : (V, 4, 4) array_like of float
        Each vehicle's rigid start pose.
    waypoints : (V, W, 4) array_like of float
        Each vehicle's waypoints: x, y, z (m), yaw (rad).
    num_scans : int
        Scans to record per vehicle.
    scan_rate_hz : float, optional
        Scans a second (a whole number of physics steps between scans).
    config : ControllerConfig, optional
        The waypoint controller's settings.

    Returns
    -------
    poses : (V, num_scans, 4, 4) ndarray of float64
        Each vehicle's pose at each scan.
    index : (V, num_scans) ndarray of int
        The waypoint each is flying to.

    Raises
    ------
    ValueError
        As `simulate`'s, or if V times `num_scans` exceeds MAX_SCANS.
    """
    start_poses = _start_poses("start_poses", start_poses)
    waypoints = _waypoints(waypoints, (len(start_poses), -1, 4))
    steps = _flight_args(num_scans, scan_rate_hz, config)
    if len(start_poses) * num_scans > MAX_SCANS:
        raise ValueError(
            f"start_poses times num_scans must be at most {MAX_SCANS} scans, got {len(start_poses)} x {num_scans}"
        )
    num_scans = int(num_scans)
    _, mx = model()
    qpos0 = jnp.asarray(_qpos(start_poses))
    run = jax.vmap(lambda q, w: _run(mx, q, w, num_scans, steps, config))
    qpos, index = run(qpos0, jnp.asarray(waypoints, dtype=jnp.float32))
    return poses_from_qpos(np.asarray(qpos)), np.asarray(index)


# ---------------------------------------------------------------- flights continued from a state
# (for closed-loop runs, where the next waypoint depends on what the vehicle has seen so far)


@dataclasses.dataclass(frozen=True)
class Flight:
    """S scans of a flight: poses (S,4,4) at each scan, index (S,) of the waypoint being flown
    to, and the vehicle's state at each scan, qpos (S,7) and qvel (S,6), to continue from."""

    poses: np.ndarray
    index: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray


def resting_state(pose) -> tuple[np.ndarray, np.ndarray]:
    """qpos (7,) and qvel (6,) of the vehicle at rest at pose (4,4), to start a `fly`."""
    return _qpos(pose), np.zeros(6)


@functools.partial(jax.jit, static_argnames=("num_scans", "steps_per_scan", "config"))
def _run_from(mx, qpos0, qvel0, waypoints, num_scans: int, steps_per_scan: int, config: ControllerConfig):
    data = mjx.make_data(mx).replace(qpos=qpos0, qvel=qvel0)

    def physics_step(carry, _):
        data, index = carry
        target = waypoints[index]
        data = mjx.step(mx, data.replace(ctrl=control(data.qpos, data.qvel, target, config)))
        index = jnp.where(_reached(data.qpos, target, config), jnp.minimum(index + 1, len(waypoints) - 1), index)
        return (data, index), None

    def scan_step(carry, _):
        carry, _ = jax.lax.scan(physics_step, carry, None, length=steps_per_scan)
        data, index = carry
        return carry, (data.qpos, data.qvel, index)

    _, (qpos, qvel, index) = jax.lax.scan(scan_step, (data, jnp.int32(0)), None, length=num_scans)
    return qpos, qvel, index


def fly(
    qpos, qvel, waypoints, num_scans: int, scan_rate_hz: float = 5.0, config: ControllerConfig = ControllerConfig()
) -> Flight:
    """Continue a flight from the state qpos (7,), qvel (6,) (a `resting_state`, or a Flight's
    last row) through waypoints (W,4: x, y, z, yaw) for num_scans scans. Compiled once per
    (num_scans, W): callers fly fixed-length pieces."""
    qpos = float_array("qpos", qpos, (7,), np.float64)
    qvel = float_array("qvel", qvel, (6,), np.float64)
    waypoints = _waypoints(waypoints, (-1, 4))
    steps = _flight_args(num_scans, scan_rate_hz, config)
    num_scans = int(num_scans)
    _, mx = model()
    qpos, qvel, index = _run_from(
        mx, jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(waypoints, dtype=jnp.float32), num_scans, steps, config
    )
    qpos = np.asarray(qpos, dtype=np.float64)
    return Flight(poses_from_qpos(qpos), np.asarray(index), qpos, np.asarray(qvel, dtype=np.float64))
