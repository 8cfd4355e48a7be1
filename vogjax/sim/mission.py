"""A simulated run: fly a scene's survey, scan with the sonar, drift the navigation, record."""

from __future__ import annotations

import dataclasses
from os import PathLike
from pathlib import Path

import numpy as np
from tqdm import tqdm

import vogjax
from vogjax import scenes
from vogjax.config import ControllerConfig, NavNoise
from vogjax.config.schema import Rule
from vogjax.geometry import rigid_pose, wrap_angle, yaw_pitch_roll
from vogjax.io.atomic import check_writable
from vogjax.io.dataset import DatasetWriter
from vogjax.sensors import ProfilingSonar, RangeSensor, as_sensor
from vogjax.sim import navigation, ranging, vehicle
from vogjax.validation import float_array

CHUNK_SCANS = 500
MAX_SCANS = vehicle.MAX_SCANS  # 23 days of scans at 5 Hz
MAX_LAPS = scenes.scene.MAX_LAPS


@dataclasses.dataclass(frozen=True)
class RunSummary:
    """What `simulate_run` wrote.

    Attributes
    ----------
    path : Path
        The run file.
    scans : int
        Scans recorded.
    duration_s : float
        Time from the first scan to the last, seconds.
    returns : float
        Share of the beams that returned.
    """

    path: Path
    scans: int
    duration_s: float
    returns: float  # fraction of beams that returned


def mission_scans(
    waypoints: np.ndarray, start_pose: np.ndarray, rate_hz: float, config: ControllerConfig = ControllerConfig()
) -> int:
    """Scans long enough to fly the waypoints at the speed limits, with a margin; at most
    MAX_SCANS (a ValueError otherwise)."""
    start_pose = rigid_pose("start_pose", start_pose)
    waypoints = float_array("waypoints", waypoints, (-1, 4), np.float64)
    Rule("number", 0, low_open=True).check("rate_hz", rate_hz)
    points = np.vstack([start_pose[:3, 3], waypoints[:, :3]])
    headings = np.concatenate([[yaw_pitch_roll(start_pose[:3, :3])[0]], waypoints[:, 3]])
    turns = np.abs(wrap_angle(np.diff(headings)))
    seconds = (
        np.linalg.norm(np.diff(points, axis=0), axis=1).sum() / config.max_speed_mps
        + turns.sum() / config.max_yaw_rate_rps
    )
    scans = np.ceil(1.4 * seconds * rate_hz) + 10
    if not scans <= MAX_SCANS:
        raise ValueError(
            f"flying these waypoints at {rate_hz:g} Hz takes {scans:.3g} scans, more than the limit of {MAX_SCANS}"
        )
    return int(scans)


def simulate_run(
    scene_name: str,
    out: str | PathLike,
    laps: int | None = None,
    seed: int = 0,
    num_scans: int | None = None,
    sensor: RangeSensor | None = None,
    noise: NavNoise | None = None,
    progress: bool = True,
    overwrite: bool = False,
) -> RunSummary:
    """Simulate the default survey of a built-in scene and write it to `out` (HDF5).

    Parameters
    ----------
    scene_name : str
        A built-in underwater scene (`vogjax.scenes.NAMES`; the warehouse is
        `simulate_lidar_run`'s).
    out : str or os.PathLike
        The run file to write.
    laps : int or None, optional
        Times the survey is flown (default 2, or with `num_scans` as many as fill them).
    seed : int, optional
        Seed of the navigation's drift and the range noise.
    num_scans : int or None, optional
        Scans recorded (default: enough for the laps; the run ends 5 s after the last waypoint).
    sensor : RangeSensor or SonarConfig or None, optional
        The sensor (default the papers' profiling sonar), at a rate of 20/n Hz (a whole number
        of physics steps between scans, so the recorded scan times k / rate_hz are the
        simulated ones: `vehicle.steps_per_scan`).
    noise : NavNoise or None, optional
        The navigation's drift (default: the papers').
    progress : bool, optional
        Show a progress bar (on stderr).
    overwrite : bool, optional
        Replace an existing `out`; without it that is an error, raised before any work.

    Returns
    -------
    RunSummary
        The file, its scans, duration and share of returns.

    Raises
    ------
    ValueError
        If `out` exists (without `overwrite`), cannot be written or its folder does not exist,
        the scene is unknown, or `laps`, `seed`, `num_scans`, `sensor` (its range noise above
        its max range included) or `noise` is out of range.
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise ValueError(f"out {str(out)!r} exists (pass overwrite=True, or --overwrite, to replace it)")
    check_writable(out)
    if not out.parent.is_dir():  # check_writable allows missing folders; the run's writer does not
        raise ValueError(f"--out {str(out)!r}: folder {str(out.parent)!r} does not exist")
    sensor = ProfilingSonar() if sensor is None else as_sensor(sensor)
    vehicle.steps_per_scan(sensor.rate_hz, "sensor.rate_hz")
    if sensor.range_noise_m > sensor.max_range_m:  # no measurement; and ranges past the run format's limit
        raise ValueError(
            f"sensor range_noise_m (--range-noise) must be at most the sensor's max_range_m of "
            f"{sensor.max_range_m:g} m, got {sensor.range_noise_m:g}"
        )
    noise = noise or NavNoise()
    if not isinstance(noise, NavNoise):
        raise ValueError(f"noise must be a NavNoise, got {type(noise).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if laps is not None and not (isinstance(laps, int) and 1 <= laps <= MAX_LAPS):
        raise ValueError(f"laps must be an integer in [1, {MAX_LAPS}], got {laps!r}")
    if num_scans is not None and not (isinstance(num_scans, int) and 1 <= num_scans <= MAX_SCANS):
        raise ValueError(f"num_scans must be an integer in [1, {MAX_SCANS}], got {num_scans!r}")
    scene = scenes.load(scene_name)
    until_done = num_scans is None  # else record exactly num_scans, flying laps enough for them
    if laps is None:
        # mission_scans has a 40% margin: 1.4 x its laps keep the vehicle busy to the last scan
        per_lap = mission_scans(scene.survey(1), scene.start_pose, sensor.rate_hz)
        laps = 2 if until_done else min(MAX_LAPS, max(2, -(-int(1.4 * num_scans) // per_lap)))
    waypoints = scene.survey(laps)
    if until_done:
        num_scans = mission_scans(waypoints, scene.start_pose, sensor.rate_hz)
    # 1. fly the survey (MJX), and stop recording once the last waypoint is reached
    truth, index = vehicle.simulate(scene.start_pose, waypoints, num_scans, sensor.rate_hz)
    arrived = np.flatnonzero(
        (index == len(waypoints) - 1) & (np.linalg.norm(truth[:, :3, 3] - waypoints[-1, :3], axis=1) < 0.2)
    )
    if until_done and len(arrived):
        num_scans = min(num_scans, int(arrived[0]) + int(sensor.rate_hz * 5))
        truth = truth[:num_scans]
    times = np.arange(num_scans) / sensor.rate_hz
    # 2. drift the navigation
    nav = navigation.drifting_navigation(truth, times, noise, seed)
    # 3. scan and record, a chunk at a time
    rng = np.random.default_rng(seed + 1)
    metadata = {
        "scene": scene_name,
        "seed": seed,
        "laps": laps,
        **sensor.metadata(),
        "nav_noise": noise.to_dict(),
        "waypoints": waypoints.tolist(),
        "vogjax_version": vogjax.__version__,
    }
    returned = 0
    with DatasetWriter(out, sensor.beams, metadata) as writer:
        chunk = max(1, min(CHUNK_SCANS, ranging.MAX_CAST_BEAMS // sensor.beams))
        for first in tqdm(
            range(0, num_scans, chunk), desc=f"simulating {scene_name}", unit="chunk", disable=not progress
        ):
            last = min(first + chunk, num_scans)
            scans = ranging.scan(scene.warp_mesh, truth[first:last] @ sensor.T_vehicle_sensor, sensor, rng)
            returned += int((~scans.no_return & ~scans.invalid).sum())
            writer.append(
                time_s=times[first:last],
                pose_truth=truth[first:last],
                pose_nav=nav[first:last],
                **sensor.dataset_fields(scans.ranges, scans.no_return, scans.invalid),
            )
    return RunSummary(Path(out), num_scans, float(times[-1]), returned / (num_scans * sensor.beams))
