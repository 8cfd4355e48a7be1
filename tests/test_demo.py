"""`vogjax demo` end to end on a short survey; a map of the analytic pier checked against the
surfaces it was scanned from (the scene benchmarks use)."""

import json

import numpy as np

import vogjax as vj
from vogjax import cli
from vogjax.scenes import analytic


def test_demo_simulates_maps_and_summarises(tmp_path, capsys):
    assert cli.main(["demo", "--out", str(tmp_path), "--scene", "boxes", "--laps", "1", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "AUC online" in printed and "boxes" in printed
    report = json.loads((tmp_path / "boxes" / "report.json").read_text())
    assert report["scene"] == "boxes" and report["scans"] > 500
    assert (tmp_path / "boxes" / "trajectory.png").stat().st_size > 10_000


def test_map_of_the_analytic_pier_lies_on_its_surfaces():
    scene = analytic.pier()
    sweep = analytic.orbit_sweep(scene, 400)
    vmap = vj.VoxelMap()
    vmap.integrate_scans(sweep.origins, sweep.points, sweep.scan_index)
    # Occupied voxels lie on the scene's surfaces: the seabed, piles or hull, within two voxels.
    centres, log_odds = vmap.voxels()
    occupied = centres[log_odds >= vmap.config.log_occupied]
    assert len(occupied) > 1000
    scene = analytic.pier()
    down = scene.cast(occupied + [0, 0, 0.25], np.tile([0.0, 0.0, -1.0], (len(occupied), 1)))
    near_seabed_or_top = np.abs(down - 0.25) <= 0.2
    probes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)
    near_side = np.zeros(len(occupied), bool)
    for direction in probes:
        start = occupied - 0.25 * direction
        near_side |= np.abs(scene.cast(start, np.tile(direction, (len(occupied), 1))) - 0.25) <= 0.2
    assert np.mean(near_seabed_or_top | near_side) > 0.97


def test_orbit_sweep_ranges_match_the_analytic_surfaces():
    scene = analytic.pier()
    sweep = analytic.orbit_sweep(scene, 50)
    starts = sweep.origins[sweep.scan_index].astype(float)
    d = sweep.points - starts
    ranges = np.linalg.norm(d, axis=1)
    assert sweep.hit.mean() > 0.5
    assert np.all(ranges[~sweep.hit] > 11.0)  # misses clear free space up to max range
    # A beam that hit ends on a surface: a step back along it is free water, a step on is not.
    ends = sweep.points[sweep.hit].astype(float)
    unit = d[sweep.hit] / ranges[sweep.hit, None]
    assert np.all(scene.cast(ends - 0.01 * unit, unit) < 0.02)
