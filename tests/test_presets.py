"""Sensor and platform presets (`vogjax.config.presets`) and `vogjax map` using them: the preset a
run's metadata picks, the settings it derives against the sensor's own figures, the user's
settings winning, a sonar run mapped bit for bit as before, and the returns past the map's reach
counted against the run file itself."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vogjax import cli
from vogjax.config import JobConfig, NavNoise, presets
from vogjax.io.dataset import Dataset
from vogjax.sim import simulate_run
from vogjax.sim.lidar_mission import DEFAULT_LIDAR, simulate_lidar_run


@pytest.fixture(scope="module")
def lidar_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("runs") / "warehouse.h5"
    simulate_lidar_run("warehouse", path, num_scans=12, progress=False)
    return path


@pytest.fixture(scope="module")
def sonar_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("runs") / "boxes.h5"
    simulate_run("boxes", path, num_scans=120, progress=False)
    return path


def metadata_of(path):
    with Dataset(path) as ds:
        return ds.metadata


def test_a_simulated_lidar_run_picks_the_lidar_and_wheel_odometry_preset(lidar_run):
    derived = presets.derive(metadata_of(lidar_run), JobConfig(), given=set())
    assert derived.preset.name == "lidar + wheel odometry"
    config = derived.config.pipeline
    # the sensor's own figures: its range (rounded up to a decimetre), 10 s of its scans a submap
    assert config.map.max_range == math.ceil(DEFAULT_LIDAR.max_range_m * 10) / 10
    assert config.scans_per_submap == round(10.0 * DEFAULT_LIDAR.rate_hz)
    assert config.map.voxel_size == 0.2
    assert config.nav_noise == presets.WHEEL_ODOMETRY
    # closures gated over a complete overlap's score, and ICP's inliers within half its reach in rms
    closures = config.loop_closure
    assert (closures.overlap_reference, closures.min_overlap_score) == ("self", 0.5)
    assert closures.max_fitness_m2 == pytest.approx((closures.icp.max_correspondence_m / 2) ** 2)
    # wheel odometry's yaw drifts: closures solve it, pitch and roll stay held
    assert config.loop_closure.icp.free == "yaw"
    assert derived.origins["loop_closure.icp.free"][1].startswith("navigation noise")
    # every setting that changed is printed, with where it came from
    text = "\n".join(derived.lines())
    changed = presets.changed_settings(derived.config)
    assert changed and all(key in text for key in changed)
    assert not derived.notes  # the map reaches as far as the sensor


def test_the_users_settings_win_and_a_short_reach_is_reported(lidar_run):
    config = JobConfig.from_document({"map": {"max_range": 20.0}, "loop_closure": {"icp": {"free": "all"}}})
    derived = presets.derive(metadata_of(lidar_run), config, given={"map.max_range", "loop_closure.icp.free"})
    assert derived.config.pipeline.map.max_range == 20.0
    assert derived.config.pipeline.loop_closure.icp.free == "all"
    assert derived.config.pipeline.map.voxel_size == 0.2  # what the user did not set still comes from the preset
    assert derived.origins["map.max_range"] == ("20.0", "your settings: preset 50.0")
    assert len(derived.notes) == 1 and f"{DEFAULT_LIDAR.max_range_m:g} m" in derived.notes[0]
    # presets off: the settings exactly as given
    off = presets.derive(metadata_of(lidar_run), config, sensor="none")
    assert off.config == config and off.preset is None


@pytest.mark.parametrize(
    ("noise", "free"),
    [
        (NavNoise(), "translation"),  # the HAUV's gyro: the papers' closures
        (NavNoise(sigma2_yaw=1e-6), "translation"),  # at the threshold, not above it
        (NavNoise(sigma2_yaw=2e-6), "yaw"),
        (NavNoise(sigma2_yaw=1e-7, sigma2_pitch=1e-5), "all"),
        (presets.UNKNOWN_ODOMETRY, "all"),
    ],
)
def test_the_closure_directions_follow_the_navigation_noise(noise, free):
    assert presets.closure_directions(noise)[0] == free


@pytest.mark.parametrize(
    ("metadata", "sensor", "voxel", "reach"),
    [
        ({"sensor": "point_cloud", "source": "bag", "sensor_config": {"message": "Image", "max_range_m": 12.0}},
         "depth_camera", 0.05, 8.0),
        ({"sensor": "point_cloud", "source": "bag", "sensor_config": {"message": "LaserScan", "max_range_m": 29.96}},
         "laser_scan", 0.05, 30.0),
        ({"sensor": "point_cloud", "source": "bag", "sensor_config": {"message": "PointCloud2", "max_range_m": 36.2}},
         "lidar", 0.2, 36.2),
    ],
)  # fmt: skip
def test_imported_runs_pick_their_sensors_preset_and_unknown_odometry(metadata, sensor, voxel, reach):
    derived = presets.derive(metadata, JobConfig(), given=set())
    assert (derived.preset.sensor, derived.preset.odometry) == (sensor, "unknown")
    assert derived.config.pipeline.map.voxel_size == voxel
    assert derived.config.pipeline.map.max_range == pytest.approx(reach)
    # nothing known absolutely: closures solve all six directions
    assert derived.config.pipeline.loop_closure.icp.free == "all"


def test_bad_preset_choices_are_refused_by_name():
    with pytest.raises(ValueError, match="sensor preset"):
        presets.derive({}, JobConfig(), sensor="radar")
    with pytest.raises(ValueError, match="config"):
        presets.derive({}, {"map": {}})
    with pytest.raises(ValueError, match="unknown setting"):
        presets.with_settings(JobConfig(), {"no_such_table.key": 1})


def test_a_sonar_runs_preset_is_the_defaults_and_its_map_is_unchanged_bit_for_bit(sonar_run, tmp_path, capsys):
    derived = presets.derive(metadata_of(sonar_run), JobConfig(), given=set())
    assert derived.preset.name == "sonar" and derived.config == JobConfig() and not derived.origins
    maps = {}
    for choice in ("auto", "none"):
        out = tmp_path / choice
        assert cli.main(["map", str(sonar_run), "--out", str(out), "--sensor-preset", choice]) == 0
        maps[choice] = out / sonar_run.stem
    err = capsys.readouterr().err
    assert 'preset "sonar"' in err and "nothing derived" in err and "settings as given" in err
    assert (maps["auto"] / "global_map.vog").read_bytes() == (maps["none"] / "global_map.vog").read_bytes()
    assert (maps["auto"] / "trajectories.csv").read_bytes() == (maps["none"] / "trajectories.csv").read_bytes()
    reports = [json.loads((maps[c] / "report.json").read_text()) for c in ("auto", "none")]
    assert reports[0]["config"] == reports[1]["config"] == json.loads(json.dumps(reports[0]["config"]))
    assert reports[0]["trajectory_rmse_m"] == reports[1]["trajectory_rmse_m"]
    assert reports[0]["auc"] == reports[1]["auc"]


def test_map_prints_the_preset_and_warns_of_returns_past_the_maps_reach(lidar_run, tmp_path, capsys):
    settings = tmp_path / "settings.toml"
    settings.write_text("[map]\nmax_range = 10.0\n")
    out = tmp_path / "maps"
    assert cli.main(["map", str(lidar_run), "--out", str(out), "--config", str(settings)]) == 0
    captured = capsys.readouterr()
    assert 'preset "lidar + wheel odometry"' in captured.err and "max_range = 10.0 (preset 50.0)" in captured.err
    assert "lidar + wheel" not in captured.out  # stdout carries the results only
    report = json.loads((out / lidar_run.stem / "report.json").read_text())
    # the reference: the run file's own ranges, counted here
    with Dataset(lidar_run) as ds:
        ranges = np.concatenate([scan.ranges[~scan.no_return] for scan in ds.batches(64)])
    assert report["returns"]["total"] == ranges.size
    assert report["returns"]["beyond_reach"] == np.count_nonzero(ranges > 10.0) > 0
    share = report["returns"]["beyond_reach_share"]
    assert f"{share:.1%} of the returns reach past the map's range (10 m)" in captured.err
    assert report["preset"]["settings"]["map.max_range"] == {"value": "10.0", "from": "your settings: preset 50.0"}


def test_map_reports_scan_matching_and_warns_when_its_registrations_fail(lidar_run, tmp_path, capsys):
    """12 scans at 10 Hz: registered at 0.5 and 1.0 s after the anchor. One ICP iteration with a
    tolerance no step meets converges nowhere: both kept the odometry's motion, and map says so."""
    settings = tmp_path / "settings.toml"
    settings.write_text("[scan_matching.icp]\nmax_iterations = 1\ntolerance = 1e-12\n")
    out = tmp_path / "maps"
    assert cli.main(["map", str(lidar_run), "--out", str(out), "--config", str(settings)]) == 0
    err = capsys.readouterr().err
    report = json.loads((out / lidar_run.stem / "report.json").read_text())
    assert report["scan_matching"] == {"enabled": True, "registered": 0, "failed": 2}
    assert "2 of 2 scans due for scan matching were not registered" in err
    # with the preset's own settings they converge, and nothing is said
    assert cli.main(["map", str(lidar_run), "--out", str(tmp_path / "plain")]) == 0
    assert "were not registered" not in capsys.readouterr().err
    plain = json.loads((tmp_path / "plain" / lidar_run.stem / "report.json").read_text())
    assert plain["scan_matching"] == {"enabled": True, "registered": 2, "failed": 0}
    errors = plain["trajectory_rmse_m"]
    assert errors["navigation"] < errors["odometry"]  # 1.2 s: already a little drift to undo
    assert (tmp_path / "plain" / lidar_run.stem / "odometry.tum").is_file()
