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
from mujoco import mjx

from vogjax.config import ControllerConfig
from vogjax.geometry import (quaternions_from_rotations, rotation_from_quaternion, rotations_from_quaternions,
                             wrap_angle, yaw_of_quaternion)
from vogjax.sim.vehicle_model import HAUV_XML

DAMPING = 150.0  # the model's joint damping: thrust needed per m/s (and per rad/s)


@functools.cache
def model() -> tuple[mujoco.MjModel, mjx.Model]:
    host = mujoco.MjModel.from_xml_string(HAUV_XML)
    return host, mjx.put_model(host)


def control(qpos, qvel, target, config: ControllerConfig):
    """Thrusts (surge, sway, heave, yaw) steering toward target (x, y, z, yaw)."""
    error = target[:3] - qpos[:3]
    distance = jnp.linalg.norm(error)
    speed = jnp.minimum(config.position_gain * distance, config.max_speed_mps)
    velocity = jnp.where(distance > 1e-9, error / jnp.maximum(distance, 1e-9) * speed, 0.0)
    force_world = DAMPING * velocity + config.velocity_gain * (velocity - qvel[:3])
    force_body = rotation_from_quaternion(qpos[3:7], jnp).T @ force_world
    yaw_rate = jnp.clip(config.yaw_gain * wrap_angle(target[3] - yaw_of_quaternion(qpos[3:7], jnp)),
                        -config.max_yaw_rate_rps, config.max_yaw_rate_rps)
    torque = DAMPING * yaw_rate + config.yaw_rate_gain * (yaw_rate - qvel[5])
    return jnp.concatenate([force_body, torque[None]])


def _reached(qpos, target, config: ControllerConfig):
    return (jnp.linalg.norm(target[:3] - qpos[:3]) < config.tolerance_m) & \
        (jnp.abs(wrap_angle(target[3] - yaw_of_quaternion(qpos[3:7], jnp))) < config.tolerance_rad)


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


def simulate(start_pose, waypoints, num_scans: int, scan_rate_hz: float = 5.0,
             config: ControllerConfig = ControllerConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Fly from start_pose (4,4) through waypoints (W,4: x, y, z, yaw); the pose at each scan
    (num_scans,4,4) and the index of the waypoint being flown to."""
    host, mx = model()
    steps = max(1, int(round(1.0 / (scan_rate_hz * host.opt.timestep))))
    qpos, index = _run(mx, jnp.asarray(_qpos(start_pose)),
                       jnp.asarray(waypoints, dtype=jnp.float32), num_scans, steps, config)
    return poses_from_qpos(np.asarray(qpos)), np.asarray(index)


def simulate_batch(start_poses, waypoints, num_scans: int, scan_rate_hz: float = 5.0,
                   config: ControllerConfig = ControllerConfig()) -> tuple[np.ndarray, np.ndarray]:
    """`simulate` for V vehicles at once (vmap): start_poses (V,4,4), waypoints (V,W,4)."""
    host, mx = model()
    steps = max(1, int(round(1.0 / (scan_rate_hz * host.opt.timestep))))
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


def fly(qpos, qvel, waypoints, num_scans: int, scan_rate_hz: float = 5.0,
        config: ControllerConfig = ControllerConfig()) -> Flight:
    """Continue a flight from the state qpos (7,), qvel (6,) (a `resting_state`, or a Flight's
    last row) through waypoints (W,4: x, y, z, yaw) for num_scans scans. Compiled once per
    (num_scans, W): callers fly fixed-length pieces."""
    host, mx = model()
    steps = max(1, int(round(1.0 / (scan_rate_hz * host.opt.timestep))))
    qpos, qvel, index = _run_from(mx, jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(waypoints, dtype=jnp.float32),
                                  num_scans, steps, config)
    qpos = np.asarray(qpos, dtype=np.float64)
    return Flight(poses_from_qpos(qpos), np.asarray(index), qpos, np.asarray(qvel, dtype=np.float64))
