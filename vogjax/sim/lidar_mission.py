"""A simulated lidar run: a ground vehicle drives a ground scene's route with a spinning lidar.

    summary = simulate_lidar_run("warehouse", "warehouse.h5")   # two laps, deskewed

Per scan the lidar's columns fire one after another over the sweep (0.1 s at 10 Hz) while the
vehicle moves, and each column is cast against the scene from where the sensor was when it
fired: the motion distortion a real spinning lidar's clouds carry. The run then stores, per
`sweep`:

- "deskewed" (default): the points deskewed with the wheel odometry (100 Hz, interpolated as
  `vogjax import` interpolates it: `vogjax.io.deskew.deskew_points`), in the sensor's frame at
  the scan's stamp: what `vogjax import` writes from a bag with per-point times;
- "raw": the points as the sensor reports them in its frame, placed as if every column had
  fired at the stamp (what `vogjax import --no-deskew` writes): motion-distorted;
- "instant": every column fired at the stamp (a sensor that does not spin): no distortion,
  the reference the other two are measured against.

Beams whose surface lies nearer than the sensor's `min_range_m` are invalid (no range, no free
space): they are dropped and the scan padded with copies of one of its own returns, as
`vogjax import` pads (a copy changes no voxel: within one scan a voxel is updated once). The
run records what it did in its metadata (`sweep`, `odometry`, `platform`).
"""

from __future__ import annotations

import dataclasses
from os import PathLike
from pathlib import Path

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

import vogjax
from vogjax import scenes
from vogjax.config import LidarConfig, NavNoise
from vogjax.config.presets import WHEEL_ODOMETRY
from vogjax.config.sensing import SonarConfig
from vogjax.geometry import rotation_from_ypr
from vogjax.io.atomic import check_writable
from vogjax.io.dataset import DatasetWriter
from vogjax.io.deskew import deskew_points
from vogjax.sensors.base import RangeSensor
from vogjax.sensors.lidar import SpinningLidar
from vogjax.sim import navigation, ranging
from vogjax.sim.ground_vehicle import ODOMETRY_RATE_HZ, GroundVehicle

SWEEPS = ("deskewed", "raw", "instant")
MAX_LAPS = scenes.scene.MAX_LAPS
MAX_SCANS = 10_000_000
CHUNK_SCANS = 50  # scans cast per call: 50 x 14,400 beams, ~60 MB of rays
DEFAULT_LIDAR = LidarConfig(range_noise_m=0.02)  # a VLP-16's, with 2 cm range noise
STOP_S = 1.0  # the run goes on this long after the vehicle stops
# What the run's metadata says of the odometry: wheel odometry drifts in x, y and yaw; the floor
# and an inclinometer give z, pitch and roll absolutely.
ODOMETRY = {
    "kind": "wheel",
    "rate_hz": ODOMETRY_RATE_HZ,
    "relative": ["x", "y", "yaw"],
    "absolute": ["z", "pitch", "roll"],
}


@dataclasses.dataclass(frozen=True)
class LidarRunSummary:
    """What `simulate_lidar_run` wrote.

    Attributes
    ----------
    path : Path
        The run file.
    scans : int
        Scans recorded.
    duration_s : float
        Time of the last scan, seconds.
    returns : float
        Share of the beams that returned.
    invalid : float
        Share of the beams that were invalid (their surface nearer than the minimum range).
    sweep : str
        How the points were stored (`SWEEPS`).
    """

    path: Path
    scans: int
    duration_s: float
    returns: float
    invalid: float
    sweep: str


class _Column(RangeSensor):
    """One column of a lidar as a sensor of its own: its rings at azimuth 0, every return kept
    (min range 0: the lidar's own minimum range is applied after the cast)."""

    kind = "lidar_column"

    def __init__(self, lidar: SpinningLidar):
        super().__init__(SonarConfig(), np.eye(4))
        self._rings = lidar.ring_directions()
        self._max_range_m = lidar.max_range_m

    beams = property(lambda self: len(self._rings))
    rate_hz = property(lambda self: 1.0)
    min_range_m = property(lambda self: 0.0)
    max_range_m = property(lambda self: self._max_range_m)

    def beam_directions(self) -> np.ndarray:
        return self._rings[:, None, :]


def simulate_lidar_run(
    scene_name: str,
    out: str | PathLike,
    laps: int | None = None,
    seed: int = 0,
    num_scans: int | None = None,
    sensor: SpinningLidar | None = None,
    noise: NavNoise | None = None,
    sweep: str = "deskewed",
    progress: bool = True,
    overwrite: bool = False,
) -> LidarRunSummary:
    """Drive a ground scene's route with a spinning lidar and write the run to `out` (HDF5).

    Parameters
    ----------
    scene_name : str
        A ground scene (`vogjax.scenes.GROUND_SCENES`: "warehouse").
    out : str or os.PathLike
        The run file to write.
    laps : int or None, optional
        Times the route is driven (default 2).
    seed : int, optional
        Seed of the odometry's drift and the range noise.
    num_scans : int or None, optional
        Scans recorded (default: until STOP_S after the vehicle stops; fewer cut the run short).
    sensor : SpinningLidar or None, optional
        The lidar (default: 16 rings over +-15 degrees, 0.4 degree columns, 10 Hz, 0.5-50 m,
        2 cm range noise, 1.8 m above the floor); its rate must divide the odometry's 100 Hz.
    noise : NavNoise or None, optional
        The wheel odometry's drift (default `WHEEL_ODOMETRY`).
    sweep : str, optional
        How the points are stored: "deskewed", "raw" or "instant" (see the module's docstring).
    progress : bool, optional
        Show a progress bar (on stderr).
    overwrite : bool, optional
        Replace an existing `out` (else that is an error, raised before any work).

    Returns
    -------
    LidarRunSummary
        What was written.

    Raises
    ------
    ValueError
        Naming the argument: `out` exists (without `overwrite`) or cannot be written, the scene
        is not a ground scene, or a setting is out of its range.
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise ValueError(f"out {str(out)!r} exists (pass overwrite=True, or --overwrite, to replace it)")
    check_writable(out)
    if scene_name not in scenes.GROUND_SCENES:
        known = ", ".join(scenes.GROUND_SCENES)
        raise ValueError(f"scene {scene_name!r} is no ground scene: a spinning lidar's run drives {known}")
    lidar = SpinningLidar(DEFAULT_LIDAR) if sensor is None else sensor
    if not isinstance(lidar, SpinningLidar):
        raise ValueError(f"sensor must be a SpinningLidar, got {type(lidar).__name__}")
    if lidar.range_noise_m > lidar.max_range_m:  # as simulate_run: refused before the drive, not after
        raise ValueError(
            f"sensor range_noise_m (--range-noise) must be at most the sensor's max_range_m of "
            f"{lidar.max_range_m:g} m, got {lidar.range_noise_m:g}"
        )
    steps = ODOMETRY_RATE_HZ / lidar.rate_hz
    if abs(steps - round(steps)) > 1e-9:
        raise ValueError(
            f"sensor.rate_hz must divide the odometry's {ODOMETRY_RATE_HZ:g} Hz (5, 10, 20 Hz, ...), "
            f"got {lidar.rate_hz!r}"
        )
    steps = int(round(steps))
    noise = WHEEL_ODOMETRY if noise is None else noise
    if not isinstance(noise, NavNoise):
        raise ValueError(f"noise must be a NavNoise, got {type(noise).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if laps is not None and not (isinstance(laps, int) and not isinstance(laps, bool) and 1 <= laps <= MAX_LAPS):
        raise ValueError(f"laps must be an integer in [1, {MAX_LAPS}], got {laps!r}")
    if num_scans is not None and not (
        isinstance(num_scans, int) and not isinstance(num_scans, bool) and 1 <= num_scans <= MAX_SCANS
    ):
        raise ValueError(f"num_scans must be an integer in [1, {MAX_SCANS}], got {num_scans!r}")
    if sweep not in SWEEPS:
        raise ValueError(f"sweep must be one of {', '.join(SWEEPS)}, got {sweep!r}")
    scene = scenes.load(scene_name)
    laps = 2 if laps is None else laps
    vehicle = GroundVehicle(scene.start_pose, scene.survey(laps))
    if num_scans is None:
        num_scans = int(np.floor((vehicle.duration_s + STOP_S) * lidar.rate_hz)) + 1
    # 1. the truth and the wheel odometry at 100 Hz, through the last scan's sweep
    odometry_steps = num_scans * steps + 1
    odometry_s = np.arange(odometry_steps) / ODOMETRY_RATE_HZ
    truth = vehicle.poses(odometry_s)
    nav = navigation.drifting_navigation(truth, odometry_s, noise, seed)
    # 2. scan, chunk by chunk
    rng = np.random.default_rng(seed + 1)
    metadata = {
        "scene": scene_name,
        "seed": seed,
        "laps": laps,
        **lidar.metadata(),
        "platform": "ground_vehicle",
        "odometry": ODOMETRY,
        "nav_noise": noise.to_dict(),
        "vehicle": {"speed_mps": vehicle.speed_mps, "route_m": vehicle.length_m, "duration_s": vehicle.duration_s},
        "sweep": _sweep_metadata(sweep, lidar),
        "waypoints": scene.survey(laps).tolist(),
        "vogjax_version": vogjax.__version__,
    }
    totals = {"returns": 0, "invalid": 0}
    with DatasetWriter(out, lidar.beams, metadata, optional=("ring",)) as writer:
        for first in tqdm(
            range(0, num_scans, CHUNK_SCANS), desc=f"simulating {scene_name}", unit="chunk", disable=not progress
        ):
            last = min(first + CHUNK_SCANS, num_scans)
            fields = _scans(scene, vehicle, lidar, np.arange(first, last), sweep, odometry_s, nav, rng, totals)
            index = np.arange(first, last) * steps
            writer.append(time_s=odometry_s[index], pose_truth=truth[index], pose_nav=nav[index], **fields)
        metadata["sweep"]["invalid_beams"] = totals["invalid"]
        writer.set_metadata(metadata)
    beams = num_scans * lidar.beams
    duration_s = float((num_scans - 1) / lidar.rate_hz)
    return LidarRunSummary(out, num_scans, duration_s, totals["returns"] / beams, totals["invalid"] / beams, sweep)


def _sweep_metadata(sweep: str, lidar: SpinningLidar) -> dict:
    """What the run's metadata says of the sweep."""
    said = {
        "deskewed": "fired along the sweep; deskewed with the wheel odometry to the sensor's pose at the stamp",
        "raw": "fired along the sweep; stored in the sensor's frame as if fired at the stamp (motion-distorted)",
        "instant": "every column fired at the stamp (no motion distortion)",
    }[sweep]
    return {
        "mode": sweep,
        "about": said,
        "stamp": "the first column's firing time",
        "sweep_s": 1.0 / lidar.rate_hz,
        "deskewed": sweep == "deskewed",
        "invalid": "beams whose surface lies within min_range_m: dropped, the scan padded with one of its returns",
    }


def _scans(
    scene,
    vehicle: GroundVehicle,
    lidar: SpinningLidar,
    scan_ids: npt.NDArray[np.int64],
    sweep: str,
    odometry_s: np.ndarray,
    nav: np.ndarray,
    rng: np.random.Generator,
    totals: dict,
) -> dict:
    """The run-file fields of some scans: every column cast from the sensor's true pose when it
    fired (or at the stamp, "instant"), then stored per `sweep`."""
    cfg = lidar.config
    columns, beams = cfg.columns, lidar.beams
    stamps = scan_ids / cfg.rate_hz
    offsets = lidar.column_offsets_s() if sweep != "instant" else np.zeros(columns)
    fired = (stamps[:, None] + offsets[None, :]).reshape(-1)
    T_world_sensor = vehicle.poses(fired) @ lidar.T_vehicle_sensor
    azimuth = np.tile(lidar.azimuths_rad(), len(scan_ids))
    T_world_column = T_world_sensor.copy()
    T_world_column[:, :3, :3] = T_world_sensor[:, :3, :3] @ rotation_from_ypr(azimuth)
    cast = ranging.scan(scene.warp_mesh, T_world_column, _Column(lidar))
    ranges = cast.ranges.reshape(len(scan_ids), beams)
    no_return = cast.no_return.reshape(len(scan_ids), beams)
    if cfg.range_noise_m > 0:
        ranges = ranges + rng.normal(0.0, cfg.range_noise_m, ranges.shape)
    # a surface within the minimum range: no range at all (the cast marks those it finds; the
    # noise can take a return below it too)
    invalid = cast.invalid.reshape(len(scan_ids), beams) | (~no_return & (ranges < cfg.min_range_m))
    no_return = no_return | (~invalid & (ranges > cfg.max_range_m))  # past its reach: nothing heard
    directions = lidar.beam_directions()[:, 0]  # sensor frame, as fired
    firing = lidar.firing_offsets_s()
    ring = lidar.rings_of_beams()
    R_vehicle_sensor, origin = lidar.T_vehicle_sensor[:3, :3], lidar.T_vehicle_sensor[:3, 3]
    out = {
        name: np.empty((len(scan_ids), *shape), dtype)
        for name, shape, dtype in (
            ("sonar_directions", (beams, 3), np.float32),
            ("ranges", (beams,), np.float32),
            ("no_return", (beams,), np.bool_),
            ("ring", (beams,), np.uint16),
        )
    }
    for row, stamp in enumerate(stamps):
        r, missing, bad = ranges[row], no_return[row], invalid[row]
        d = directions
        if sweep == "deskewed":
            d, r = _deskewed(d, r, missing, firing, stamp, odometry_s, nav, lidar.T_vehicle_sensor)
        keep = np.flatnonzero(~bad)
        totals["invalid"] += int(bad.sum())
        totals["returns"] += int((~missing & ~bad).sum())
        if len(keep) < beams:  # pad with copies of a return (any kept beam when none returned)
            returned = keep[~missing[keep]]
            filler = returned[0] if len(returned) else (keep[0] if len(keep) else None)
            if filler is None:
                raise ValueError(
                    f"scan at {stamp:.3f} s: every beam hit a surface within min_range_m {cfg.min_range_m:g} m"
                )
            keep = np.concatenate([keep, np.full(beams - len(keep), filler)])
        out["sonar_directions"][row] = (d[keep] @ R_vehicle_sensor.T).astype(np.float32)
        out["ranges"][row] = np.where(missing[keep], np.nan, r[keep])
        out["no_return"][row] = missing[keep]
        out["ring"][row] = ring[keep]
    out["sonar_origin"] = np.tile(origin, (len(scan_ids), 1)).astype(np.float32)
    # float32 directions: renormalised so the run's unit-vector check holds exactly as stored
    norms = np.linalg.norm(out["sonar_directions"].astype(np.float64), axis=-1, keepdims=True)
    out["sonar_directions"] = (out["sonar_directions"] / norms).astype(np.float32)
    return out


def _deskewed(
    directions: np.ndarray,
    ranges: np.ndarray,
    no_return: np.ndarray,
    offsets_s: np.ndarray,
    stamp_s: float,
    odometry_s: np.ndarray,
    nav: np.ndarray,
    T_vehicle_sensor: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One scan's beams deskewed with the odometry: each return moved from the sensor's pose
    when it fired to its pose at the stamp (`deskew_points`), each beam without a return turned
    the same way (deskewing is affine in the point: its linear part turns a direction)."""
    vectors = np.empty_like(directions)
    out_ranges = np.full(len(ranges), np.nan)
    hit = ~no_return
    points = directions[hit] * ranges[hit, None]
    moved = deskew_points(points, offsets_s[hit], stamp_s, odometry_s, nav, T_vehicle_sensor)
    out_ranges[hit] = np.linalg.norm(moved, axis=1)
    vectors[hit] = moved
    if no_return.any():
        args = (offsets_s[no_return], stamp_s, odometry_s, nav, T_vehicle_sensor)
        tip = deskew_points(directions[no_return], *args)
        vectors[no_return] = tip - deskew_points(np.zeros((int(no_return.sum()), 3)), *args)
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True), out_ranges
