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

from vogjax.scenes.vehicle_model import HAUV_XML

DAMPING = 150.0  # the model's joint damping: thrust needed per m/s (and per rad/s)


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    max_speed_mps: float = 0.25
    max_yaw_rate_rps: float = 0.15
    position_gain: float = 0.6  # desired speed per metre of error, 1/s
    yaw_gain: float = 0.8  # desired yaw rate per radian of error, 1/s
    velocity_gain: float = 300.0  # extra thrust per m/s of velocity error, N s/m
    yaw_rate_gain: float = 120.0  # extra torque per rad/s of yaw-rate error, N m s
    tolerance_m: float = 0.15  # a waypoint is reached within this distance ...
    tolerance_rad: float = 0.05  # ... and this heading error


@functools.cache
def model() -> tuple[mujoco.MjModel, mjx.Model]:
    host = mujoco.MjModel.from_xml_string(HAUV_XML)
    return host, mjx.put_model(host)


def _yaw(quaternion):
    w, x, y, z = quaternion
    return jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _wrap(angle):
    return (angle + jnp.pi) % (2 * jnp.pi) - jnp.pi


def _rotation(quaternion):
    w, x, y, z = quaternion
    return jnp.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def control(qpos, qvel, target, config: ControllerConfig):
    """Thrusts (surge, sway, heave, yaw) steering toward target (x, y, z, yaw)."""
    error = target[:3] - qpos[:3]
    distance = jnp.linalg.norm(error)
    speed = jnp.minimum(config.position_gain * distance, config.max_speed_mps)
    velocity = jnp.where(distance > 1e-9, error / jnp.maximum(distance, 1e-9) * speed, 0.0)
    force_world = DAMPING * velocity + config.velocity_gain * (velocity - qvel[:3])
    force_body = _rotation(qpos[3:7]).T @ force_world
    yaw_rate = jnp.clip(config.yaw_gain * _wrap(target[3] - _yaw(qpos[3:7])),
                        -config.max_yaw_rate_rps, config.max_yaw_rate_rps)
    torque = DAMPING * yaw_rate + config.yaw_rate_gain * (yaw_rate - qvel[5])
    return jnp.concatenate([force_body, torque[None]])


def _reached(qpos, target, config: ControllerConfig):
    return (jnp.linalg.norm(target[:3] - qpos[:3]) < config.tolerance_m) & \
        (jnp.abs(_wrap(target[3] - _yaw(qpos[3:7]))) < config.tolerance_rad)


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


def _qpos(pose: np.ndarray) -> np.ndarray:
    quaternion = np.zeros(4)
    mujoco.mju_mat2Quat(quaternion, np.ascontiguousarray(pose[:3, :3]).reshape(-1))
    return np.concatenate([pose[:3, 3], quaternion])


def poses_from_qpos(qpos: np.ndarray) -> np.ndarray:
    """(...,7) MuJoCo free-joint positions -> (...,4,4) poses."""
    qpos = np.asarray(qpos, dtype=np.float64)
    flat = qpos.reshape(-1, 7)
    out = np.tile(np.eye(4), (len(flat), 1, 1))
    for n, q in enumerate(flat):
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, q[3:])
        out[n, :3, :3] = rotation.reshape(3, 3)
        out[n, :3, 3] = q[:3]
    return out.reshape(*qpos.shape[:-1], 4, 4)


def simulate(start_pose, waypoints, num_scans: int, scan_rate_hz: float = 5.0,
             config: ControllerConfig = ControllerConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Fly from start_pose (4,4) through waypoints (W,4: x, y, z, yaw); the pose at each scan
    (num_scans,4,4) and the index of the waypoint being flown to."""
    host, mx = model()
    steps = max(1, int(round(1.0 / (scan_rate_hz * host.opt.timestep))))
    qpos, index = _run(mx, jnp.asarray(_qpos(np.asarray(start_pose, float))),
                       jnp.asarray(waypoints, dtype=jnp.float32), num_scans, steps, config)
    return poses_from_qpos(np.asarray(qpos)), np.asarray(index)


def simulate_batch(start_poses, waypoints, num_scans: int, scan_rate_hz: float = 5.0,
                   config: ControllerConfig = ControllerConfig()) -> tuple[np.ndarray, np.ndarray]:
    """`simulate` for V vehicles at once (vmap): start_poses (V,4,4), waypoints (V,W,4)."""
    host, mx = model()
    steps = max(1, int(round(1.0 / (scan_rate_hz * host.opt.timestep))))
    qpos0 = jnp.asarray(np.stack([_qpos(np.asarray(p, float)) for p in start_poses]))
    run = jax.vmap(lambda q, w: _run(mx, q, w, num_scans, steps, config))
    qpos, index = run(qpos0, jnp.asarray(waypoints, dtype=jnp.float32))
    return poses_from_qpos(np.asarray(qpos)), np.asarray(index)
