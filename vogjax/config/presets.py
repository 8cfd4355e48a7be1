"""Sensor and platform presets chosen from a run: what the run's metadata says it was recorded
with picks the map's reach and voxel size, the submaps' length, the loop-closure search grid and
registration cloud, and the navigation noise; the navigation noise in effect then picks which
directions a loop closure solves.

    derived = derive(dataset.metadata, JobConfig(), given=set())
    derived.config            # the settings to map the run with
    derived.lines()           # what `vogjax map` prints: the preset and every setting it derived

Sensors (the run's `sensor`, and for an imported cloud its `sensor_config.message`):

| preset | sensor | settings |
| --- | --- | --- |
| `sonar` | `profiling_sonar` | none: the papers' (Sodhi et al., Ho), the defaults |
| `lidar` | `spinning_lidar`, PointCloud2 | 0.2 m voxels, its reach, 10 s submaps, 0.3/0.4 m grids, scan matching |
| `depth_camera` | an imported depth Image | 0.05 m voxels, reach capped at 8 m, 10 s submaps, 0.1 m grids |
| `laser_scan` | an imported LaserScan | 0.05 m voxels, the sensor's reach, 10 s submaps, 0.1 m grids |

(grids: the closure search's x-y grid, then the registered clouds' voxels). Every non-sonar
preset gates the closure search's overlap over a complete overlap's score (`overlap_reference`
"self", at least 0.5) and ICP's fitness at half its correspondence cap, in rms.

Odometry (the run's `odometry.kind`; a simulated sonar run has none and is the HAUV's; an
imported run has none either and its odometry is `unknown`):

| odometry | navigation noise |
| --- | --- |
| `hauv` | the paper's (DVL and gyro: x, y, yaw drift slowly; depth, pitch, roll absolute) |
| `wheel` | `WHEEL_ODOMETRY`: x, y and yaw drift (yaw 1e-5 rad^2/s); z, pitch, roll absolute |
| `unknown` | as `wheel` in x, y and yaw, and z, pitch and roll weak too (nothing known absolutely) |

Loop-closure directions (`[loop_closure.icp] free`, and `[scan_matching.icp] free` where scan
matching is on), from the navigation noise in effect (the
preset's or the settings file's): "translation" (the rotation kept from the estimate, as the
papers do) while the yaw drifts at most `WEAK_YAW_RAD2_PER_S`; "yaw" (x, y, z and yaw; pitch
and roll held) when the yaw drifts faster; "all" six when pitch or roll drifts faster than
`WEAK_TILT_RAD2_PER_S` too.

A setting the user gave (in the settings file, or through `--preset paper`) wins over the
preset; `Derived.origins` says where every derived setting came from.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from typing import Any

from vogjax.config.maps import MAX_RANGE_VOXELS
from vogjax.config.pipeline import JobConfig
from vogjax.config.schema import rule_of
from vogjax.config.sensing import NavNoise
from vogjax.config.settings_file import settings_of, toml_value

# A ground vehicle's wheel odometry: x, y and yaw drift (the heading random-walks at 0.18 degrees
# per square-root second: wheel slip, 100 times the HAUV gyro's variance); the floor and an
# inclinometer give z, pitch and roll.
WHEEL_ODOMETRY = NavNoise(
    sigma2_x=1e-3, sigma2_y=1e-3, sigma2_yaw=1e-5, sigma2_z=1e-6, sigma2_pitch=1e-7, sigma2_roll=1e-7
)
# Odometry of unknown kind (an imported nav_msgs/Odometry): as wheel odometry, with z, pitch and
# roll drifting too.
UNKNOWN_ODOMETRY = WHEEL_ODOMETRY.replace(sigma2_z=1e-3, sigma2_pitch=1e-5, sigma2_roll=1e-5)
# Above these the navigation's yaw (pitch, roll) is weak: 1e-6 rad^2/s is 0.57 degrees (1 sigma)
# after 100 s; the HAUV's gyro drifts 1e-7, wheel odometry 1e-5. A lidar submap's ICP resolves
# its rotation far better than either.
WEAK_YAW_RAD2_PER_S = 1e-6
WEAK_TILT_RAD2_PER_S = 1e-6
SENSORS = ("sonar", "lidar", "depth_camera", "laser_scan")
ODOMETRY = ("hauv", "wheel", "unknown")
CHOICES = ("auto", "none", *SENSORS)  # `vogjax map --sensor-preset`
SUBMAP_S = 10.0  # a submap of a fast sensor: 10 s of scans
MAX_BATCH_BEAMS = 1 << 21  # beams read per batch: 2M (a lidar's 145 scans; 48 MB of float64 end points)


@dataclasses.dataclass(frozen=True)
class Preset:
    """The preset a run's metadata picks.

    Attributes
    ----------
    sensor : str
        The sensor preset (`SENSORS`).
    odometry : str
        The odometry's kind (`ODOMETRY`).
    reason : str
        What in the metadata picked them, in words.
    settings : dict of str to value
        The settings it sets, by their place in the settings file ("map.voxel_size", ...).
    """

    sensor: str
    odometry: str
    reason: str
    settings: dict[str, Any]

    @property
    def name(self) -> str:
        """ "sonar", or e.g. "lidar + wheel odometry"."""
        return self.sensor if self.odometry == "hauv" else f"{self.sensor} + {self.odometry} odometry"


@dataclasses.dataclass(frozen=True)
class Derived:
    """The settings a run is mapped with, and where each derived one came from.

    Attributes
    ----------
    preset : Preset
        The preset the run picked (None when presets are off).
    config : JobConfig
        The settings to map it with.
    origins : dict of str to (str, str)
        Every setting the preset or the navigation-noise rule decided, or the user kept over
        them: "table.key" -> (its value as TOML, where it came from: "preset", "navigation
        noise", or "your settings" with the preset's value).
    notes : list of str
        What the user should know before the run is mapped (a reach cut short).
    """

    preset: Preset | None
    config: JobConfig
    origins: dict[str, tuple[str, str]]
    notes: list[str]

    def lines(self) -> list[str]:
        """What `vogjax map` prints about the run's settings (a few lines).

        Returns
        -------
        list of str
            The preset and why, the settings by origin, the notes.
        """
        if self.preset is None:
            return ["settings as given (sensor presets off)", *self.notes]
        out = [f'preset "{self.preset.name}" ({self.preset.reason})']
        groups: dict[str, list[str]] = {}
        for key, (value, origin) in self.origins.items():
            groups.setdefault(origin.split(":")[0], []).append(f"{key} = {value}{_after(origin)}")
        for origin in ("preset", "navigation noise", "your settings"):
            if origin in groups:
                out.append(f"  {_heading(origin)}: {', '.join(groups[origin])}")
        if len(out) == 1:
            out.append("  the defaults (the papers' settings): nothing derived")
        return out + self.notes

    def to_dict(self) -> dict:
        """What report.json records of it.

        Returns
        -------
        dict
            ``name``, ``sensor``, ``odometry``, ``reason`` and ``settings`` (key -> {"value",
            "from"}), ``notes``.
        """
        if self.preset is None:
            return {"name": None, "notes": list(self.notes)}
        return {
            "name": self.preset.name,
            "sensor": self.preset.sensor,
            "odometry": self.preset.odometry,
            "reason": self.preset.reason,
            "settings": {key: {"value": value, "from": origin} for key, (value, origin) in self.origins.items()},
            "notes": list(self.notes),
        }


def _heading(origin: str) -> str:
    return {
        "preset": "set by the preset",
        "navigation noise": "from the navigation noise",
        "your settings": "yours, kept over the preset's",
    }[origin]


def _after(origin: str) -> str:
    """ " (preset: 0.2)" after a setting the user kept, "" otherwise."""
    return f" ({origin.split(': ', 1)[1]})" if ": " in origin else ""


def sensor_of(metadata: dict) -> tuple[str, str]:
    """The sensor preset a run's metadata names, and why.

    Parameters
    ----------
    metadata : dict
        The run's metadata (`Dataset.metadata`).

    Returns
    -------
    (str, str)
        The preset (`SENSORS`) and what picked it.
    """
    kind = metadata.get("sensor", "profiling_sonar")
    config = metadata.get("sensor_config", metadata.get("sonar", {}))
    config = config if isinstance(config, dict) else {}
    if kind == "spinning_lidar":
        rings = config.get("rings", "?")
        return "lidar", f"a spinning lidar, {rings} rings, reaching {_reach(metadata):g} m"
    if kind == "point_cloud":
        message = config.get("message", "PointCloud2")
        said = {"PointCloud2": "lidar", "Image": "depth_camera", "LaserScan": "laser_scan"}.get(message, "lidar")
        return said, f"imported {message} scans reaching {_reach(metadata):g} m"
    return "sonar", "a profiling sonar" if kind == "profiling_sonar" else f"sensor {kind!r}, read as a sonar"


def odometry_of(metadata: dict) -> str:
    """The odometry's kind: the run's `odometry.kind`; else "unknown" for an imported run (it
    has a `source`), "hauv" for a simulated one.

    Parameters
    ----------
    metadata : dict
        The run's metadata.

    Returns
    -------
    str
        One of `ODOMETRY`.
    """
    odometry = metadata.get("odometry")
    if isinstance(odometry, dict) and odometry.get("kind") in ODOMETRY:
        return odometry["kind"]
    return "unknown" if "source" in metadata else "hauv"


def _sensor_value(metadata: dict, name: str, default: float) -> float:
    """The sensor's setting `name` from the run's metadata; `default` where it is missing or not
    a positive finite number."""
    config = metadata.get("sensor_config", metadata.get("sonar", {}))
    try:
        value = float(config.get(name, default))
    except (AttributeError, TypeError, ValueError):
        return default
    return value if math.isfinite(value) and value > 0 else default


def _reach(metadata: dict) -> float:
    return _sensor_value(metadata, "max_range_m", 11.0)


def _rate(metadata: dict) -> float:
    return _sensor_value(metadata, "rate_hz", 10.0)


def _beams(metadata: dict) -> int:
    config = metadata.get("sensor_config", {})
    if not isinstance(config, dict):
        return 1
    if "rings" in config and "column_deg" in config:
        try:
            return max(1, int(config["rings"]) * int(round(360.0 / float(config["column_deg"]))))
        except (TypeError, ValueError, ZeroDivisionError):
            return 1
    beams = config.get("beams", 1)
    return beams if isinstance(beams, int) and beams > 0 else 1


def preset_for(metadata: dict, sensor: str = "auto") -> Preset:
    """The preset of a run: its sensor's and its odometry's settings.

    Parameters
    ----------
    metadata : dict
        The run's metadata.
    sensor : str, optional
        "auto" (from the metadata) or one of `SENSORS` (that sensor's preset, whatever the run
        says; the odometry still from the metadata).

    Returns
    -------
    Preset
        The preset.

    Raises
    ------
    ValueError
        If `sensor` is not "auto" or one of `SENSORS`.
    """
    if sensor not in ("auto", *SENSORS):
        raise ValueError(f"sensor must be one of auto, {', '.join(SENSORS)}, got {sensor!r}")
    found, reason = sensor_of(metadata)
    if sensor != "auto":
        found, reason = sensor, f"asked for; the run's sensor: {reason}"
    odometry = odometry_of(metadata)
    settings = dict(_sensor_settings(found, _reach(metadata), _rate(metadata), _beams(metadata)))
    noise = {"hauv": None, "wheel": WHEEL_ODOMETRY, "unknown": UNKNOWN_ODOMETRY}[odometry]
    if noise is not None:
        settings.update({f"nav_noise.{key}": value for key, value in noise.to_dict().items()})
    said = {"hauv": "the HAUV's navigation", "wheel": "wheel odometry", "unknown": "odometry of unknown kind"}
    return Preset(found, odometry, f"{reason}; {said[odometry]}", settings)


def _sensor_settings(sensor: str, reach_m: float, rate_hz: float, beams: int) -> dict[str, Any]:
    """The settings of a sensor preset for a sensor reaching `reach_m` at `rate_hz`."""
    if sensor == "sonar":
        return {}
    voxel = {"lidar": 0.2, "depth_camera": 0.05, "laser_scan": 0.05}[sensor]
    reach = min(reach_m, 8.0) if sensor == "depth_camera" else reach_m
    reach = min(math.ceil(reach * 10) / 10, MAX_RANGE_VOXELS * voxel)  # up to a decimetre, within the map's bound
    grid = {"lidar": 0.3, "depth_camera": 0.1, "laser_scan": 0.1}[sensor]
    cloud = {"lidar": 0.4, "depth_camera": 0.1, "laser_scan": 0.1}[sensor]
    settings = {
        "map.voxel_size": voxel,
        "map.max_range": float(reach),
        "pipeline.scans_per_submap": max(10, int(round(SUBMAP_S * rate_hz))),
        "pipeline.batch_scans": max(1, min(200, MAX_BATCH_BEAMS // beams)),
        "pipeline.eps_move_m": voxel / 2,
        "loop_closure.registration_voxel_m": cloud,
        "loop_closure.correlative.resolution_m": grid,
        "loop_closure.correlative.yaw_step_rad": 0.01,
        "loop_closure.icp.max_correspondence_m": round(1.5 * cloud, 6),
        "loop_closure.max_refinement_m": round(2 * grid, 6),
        # the inliers' rms distance at most half the correspondence cap, as the papers' 0.02 m^2
        # at 0.3 m: two submaps of a wide-reaching sensor, each bent by its own drift, sampled
        # a registration voxel apart, sit farther apart than the sonar's swaths
        "loop_closure.max_fitness_m2": round((1.5 * cloud / 2) ** 2, 6),
        # the peak's score over a complete overlap's: the raw score stays near 0.4 even at the
        # truth on a lidar's planes, so the sonar's 0.3 rejected most true revisits; at least
        # half of one cloud explained by the other
        "loop_closure.overlap_reference": "self",
        "loop_closure.min_overlap_score": 0.5,
    }
    if sensor == "lidar":  # a spinning lidar's scans overlap scan to scan: they correct the odometry
        settings["scan_matching.enabled"] = True
    return settings


def closure_directions(noise: NavNoise) -> tuple[str, str]:
    """The directions a loop closure solves for a navigation noise, and why.

    Parameters
    ----------
    noise : NavNoise
        The navigation noise in effect.

    Returns
    -------
    (str, str)
        `IcpConfig.free` ("translation", "yaw" or "all") and the reason, in words.
    """
    tilt = max(noise.sigma2_pitch, noise.sigma2_roll)
    if tilt > WEAK_TILT_RAD2_PER_S:
        return "all", f"pitch/roll drift {tilt:g} rad^2/s > {WEAK_TILT_RAD2_PER_S:g}"
    if noise.sigma2_yaw > WEAK_YAW_RAD2_PER_S:
        return "yaw", f"yaw drift {noise.sigma2_yaw:g} rad^2/s > {WEAK_YAW_RAD2_PER_S:g}"
    return "translation", f"yaw drift {noise.sigma2_yaw:g} rad^2/s <= {WEAK_YAW_RAD2_PER_S:g}"


def given_settings(document: dict) -> set[str]:
    """The settings a parsed settings file sets, by their place in the file ("map.voxel_size").

    Parameters
    ----------
    document : dict
        The parsed TOML document.

    Returns
    -------
    set of str
        The dotted keys of its leaves.
    """
    out: set[str] = set()

    def walk(prefix: str, node: dict) -> None:
        for key, value in node.items():
            path = f"{prefix}.{key}" if prefix else str(key)
            if isinstance(value, dict):
                walk(path, value)
            else:
                out.add(path)

    walk("", document)
    return out


def changed_settings(config: JobConfig, base: JobConfig | None = None) -> set[str]:
    """The settings of `config` that differ from `base` (default: the defaults), by their place in
    the settings file: what a caller set, when no settings file says.

    Parameters
    ----------
    config : JobConfig
        The settings.
    base : JobConfig or None, optional
        What they are compared with.

    Returns
    -------
    set of str
        The dotted keys that differ.
    """
    mine, theirs = settings_of(config), settings_of(base or JobConfig())
    return {key for key, value in mine.items() if theirs[key] != value}


def with_settings(config: JobConfig, settings: dict[str, Any]) -> JobConfig:
    """`config` with some settings replaced, each checked by its rule.

    Parameters
    ----------
    config : JobConfig
        The settings to start from.
    settings : dict of str to value
        "table.key" (as `settings_of` spells them) -> the new value.

    Returns
    -------
    JobConfig
        The new settings.

    Raises
    ------
    ValueError
        If a key is unknown or a value breaks its rule.
    """
    tables = JobConfig.tables()
    document: dict = {}
    for path, value in settings.items():
        table = next((t for t in sorted(tables, key=len, reverse=True) if path.startswith(t + ".")), None)
        if table is None:
            raise ValueError(f"unknown setting {path!r}")
        node = document.setdefault(table, {})
        *inner, key = path[len(table) + 1 :].split(".")
        for name in inner:
            node = node.setdefault(name, {})
        node[key] = value
    return JobConfig.from_document(document, config)


def derive(metadata: dict, config: JobConfig, given: Iterable[str] | None = None, sensor: str = "auto") -> Derived:
    """The settings to map a run with: `config`, the run's preset under what the user gave, then
    the closure directions from the navigation noise in effect.

    Parameters
    ----------
    metadata : dict
        The run's metadata.
    config : JobConfig
        The settings as the user gave them (defaults, `--preset`, settings file).
    given : iterable of str or None, optional
        The settings the user set ("table.key"): they win over the preset. None: those that
        differ from the defaults.
    sensor : str, optional
        "auto" (the preset from the metadata), "none" (no preset: `config` as it is) or one of
        `SENSORS`.

    Returns
    -------
    Derived
        The settings and where each derived one came from.

    Raises
    ------
    ValueError
        If `sensor` is not one of `CHOICES` or `config` is not a JobConfig.
    """
    if not isinstance(config, JobConfig):
        raise ValueError(f"config must be a JobConfig, got {type(config).__name__}")
    if sensor not in CHOICES:
        raise ValueError(f"sensor preset must be one of {', '.join(CHOICES)}, got {sensor!r}")
    given = changed_settings(config) if given is None else set(given)
    if sensor == "none":
        return Derived(None, config, {}, _reach_notes(metadata, config, given))
    preset = preset_for(metadata, sensor)
    current = settings_of(config)
    rules = _rules()
    origins: dict[str, tuple[str, str]] = {}
    applied = {}
    for key, value in preset.settings.items():
        literal = toml_value(rules[key], value)
        if key in given:
            if current[key] != literal:
                origins[key] = (current[key], f"your settings: preset {literal}")
        elif current[key] != literal:
            applied[key] = value
            origins[key] = (literal, "preset")
    config = with_settings(config, applied) if applied else config
    free, why = closure_directions(config.pipeline.nav_noise)
    keys = ["loop_closure.icp.free"] + (["scan_matching.icp.free"] if config.pipeline.scan_matching.enabled else [])
    for key in keys:
        section = config.pipeline.loop_closure if key.startswith("loop") else config.pipeline.scan_matching
        if key not in given and section.icp.free != free:
            config = with_settings(config, {key: free})
            origins[key] = (toml_value(rules[key], free), f"navigation noise: {why}")
    return Derived(preset, config, origins, _reach_notes(metadata, config, given))


def _rules() -> dict:
    """Each setting's Rule by its place in the settings file."""
    out = {}

    def walk(prefix: str, owner, nested: bool) -> None:
        for field in dataclasses.fields(owner):
            if rule_of(field).kind != "section":
                out[f"{prefix}.{field.name}"] = rule_of(field)
            elif nested:
                walk(f"{prefix}.{field.name}", getattr(owner, field.name), True)

    config = JobConfig()
    for table, path in JobConfig.tables().items():
        owner = getattr(config, path[0])
        if len(path) == 2 and path[1]:
            owner = getattr(owner, path[1])
        walk(table, owner, path[1:] != ("",))
    return out


def _reach_notes(metadata: dict, config: JobConfig, given: set[str]) -> list[str]:
    """A note when the sensor reaches past the map's max_range (its far returns become free space)."""
    reach, limit = _reach(metadata), config.pipeline.map.max_range
    if reach <= limit:
        return []
    whose = "your settings'" if "map.max_range" in given else "the preset's"
    return [
        f"  note: the run's returns reach {reach:g} m, past {whose} [map] max_range = {limit:g} m: returns "
        f"beyond it clear free space up to {limit:g} m and mark nothing occupied"
    ]
