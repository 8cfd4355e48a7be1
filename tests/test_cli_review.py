"""What a review of the command line found (2026-12-04): settings read from a pipe, a file's
planner seed, inputs inside the folder `map --overwrite` replaces, a damaged run among several,
a map the evaluation cannot score, settings `config --check` passed that the commands refused
late, Python warnings, and an --out that names no file."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import warnings

import h5py
import numpy as np
import pytest

from vogjax import cli

from .test_fuzz_cli import SIM_SCANS, TINY_SETTINGS, check_refusal, run_cli


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("review") / "run.h5"
    assert cli.main(["simulate", "--scene", "boxes", "--scans", str(SIM_SCANS), "--out", str(path), "-q"]) == 0
    return path


def pipe_of(text: str) -> str:
    """A path that reads `text` once, as ``--config <(...)`` gives (a second read is empty)."""
    read, write = os.pipe()
    os.write(write, text.encode())
    os.close(write)
    return f"/dev/fd/{read}"


def test_map_reads_a_piped_config_once(run_file, tmp_path, capsys, monkeypatch):
    """The file was read twice (settings, then which were given): from a pipe the second read
    was empty, so the sensor preset overrode the user's voxel size without a word."""
    from vogjax import report

    taken = {}

    def capture(paths, out, config, **kwargs):
        taken["config"], taken["given"] = config, kwargs.get("given")
        raise _Stop

    monkeypatch.setattr(report, "map_runs", capture)
    with pytest.raises(_Stop):
        cli.main(
            ["map", str(run_file), "--out", str(tmp_path / "maps"), "--config", pipe_of("[map]\nvoxel_size = 0.3\n")]
        )
    assert taken["config"].pipeline.map.voxel_size == 0.3
    assert "map.voxel_size" in taken["given"]


@pytest.mark.parametrize("seed, expected", [(None, 5), (3, 3)])
def test_explore_takes_the_files_seed_unless_seed_is_given(seed, expected):
    from vogjax.sim.explore import load_settings

    planner, _ = load_settings(pipe_of("[planner]\nmax_nodes = 7\nseed = 5\n"), "boxes", seed)
    assert (planner.max_nodes, planner.seed) == (7, expected)
    assert load_settings(None, "boxes", None)[0].seed == 0


def test_explore_seeds_the_run_with_the_files_seed(tmp_path, capsys, monkeypatch):
    from vogjax.sim import explore

    taken = {}

    def capture(*args, **kwargs):
        taken.update(kwargs)
        raise _Stop

    monkeypatch.setattr(explore, "explore", capture)
    settings = tmp_path / "s.toml"
    settings.write_text("[planner]\nseed = 5\n")
    with pytest.raises(_Stop):
        cli.main(
            [
                "explore",
                "--scene",
                "boxes",
                "--submaps",
                "1",
                "--out",
                str(tmp_path / "e.h5"),
                "--config",
                str(settings),
            ]
        )
    assert taken["seed"] == 5 and taken["planner_config"].seed == 5


@pytest.mark.parametrize("inside", ["run", "config"])
def test_map_overwrite_refuses_to_replace_a_folder_holding_its_inputs(run_file, tmp_path, capsys, inside):
    """`map out/run/run.h5 --out out --overwrite` replaced out/run, the run with it."""
    folder = tmp_path / "out" / "run"
    folder.mkdir(parents=True)
    run = shutil.copy(run_file, folder / "run.h5") if inside == "run" else run_file
    settings = folder / "s.toml" if inside == "config" else tmp_path / "s.toml"
    settings.write_text(TINY_SETTINGS)
    before = sorted(p.name for p in folder.iterdir())
    code, _, err = run_cli(["map", run, "--out", tmp_path / "out", "--config", settings, "--overwrite", "-q"], capsys)
    check_refusal(code, err, ["lies inside the output folder"], inside)
    assert sorted(p.name for p in folder.iterdir()) == before


def test_a_run_whose_sensor_is_damaged_is_refused_before_any_is_mapped(run_file, tmp_path, capsys):
    """Of good.h5 and bad.h5 (a negative sensor range), good was mapped and published, then
    the error named no file."""
    good, bad = tmp_path / "good.h5", tmp_path / "bad.h5"
    shutil.copy(run_file, good)
    shutil.copy(run_file, bad)
    with h5py.File(bad, "r+") as f:
        metadata = json.loads(f.attrs["metadata"])
        metadata["sensor_config"]["max_range_m"] = -1.0
        encoded = json.dumps(metadata)
        f.attrs["metadata"] = encoded
        f.attrs["metadata_sha256"] = hashlib.sha256(encoded.encode()).hexdigest()
    code, _, err = run_cli(["map", good, bad, "--out", tmp_path / "maps", "-q"], capsys)
    check_refusal(code, err, ["bad.h5"], "map good bad")
    assert "max_range_m" in err
    assert not (tmp_path / "maps").exists()


def test_a_map_too_coarse_to_score_is_reported_not_refused(run_file, tmp_path, capsys):
    """A reach of a micrometre observes no voxel of the truth: the ROC (it needs both kinds) raised
    after all the mapping, and nothing was written. Now the AUCs are null."""
    settings = tmp_path / "coarse.toml"
    settings.write_text(TINY_SETTINGS + "[map]\nmax_range = 1e-6\n")
    code, _, err = run_cli(["map", run_file, "--out", tmp_path / "maps", "--config", settings, "-q"], capsys)
    assert code == 0, err
    report = json.loads((tmp_path / "maps" / "run" / "report.json").read_text())
    assert report["auc"]["online"] is None and not (tmp_path / "maps" / "run" / "roc.png").exists()


@pytest.mark.parametrize(
    "table, setting, named",
    [
        ("planner", "risk_weight = 1.0", "planner.risk_weight"),  # needs a callable no CLI can give
        ("planner", "collision_level = 15", "planner.collision_level"),  # 3.3 km voxels, refused after 27 s
        ("planner", "gain_level = 14", "planner.gain_level"),
    ],
)
def test_explore_settings_the_command_would_refuse_late_are_refused_by_check(tmp_path, capsys, table, setting, named):
    path = tmp_path / "s.toml"
    path.write_text(f"[{table}]\n{setting}\n")
    code, _, err = run_cli(["config", "--check", path, "--for", "explore"], capsys)
    check_refusal(code, err, [named], setting)


def test_report_surface_points_below_three_are_refused_by_check(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_text("[report]\nsurface_points = 2\n")
    code, _, err = run_cli(["config", "--check", path], capsys)
    check_refusal(code, err, ["surface_points"], "surface_points = 2")


@pytest.mark.parametrize("out", ["", "/"])
def test_explore_out_that_names_no_file_is_refused_naming_it(capsys, out):
    code, _, err = run_cli(["explore", "--scene", "boxes", "--submaps", "1", "--out", out], capsys)
    check_refusal(code, err, ["--out"], repr(out))


def test_warnings_are_one_line_each_once(capsys):
    """A RuntimeWarning of ours printed as Python does (path, line, the source line below it),
    twice when raised twice; now `vogjax CMD: warning: ...`, once. Others' need --verbose."""
    from vogjax import slam
    from vogjax.config import NavNoise

    with cli._warnings_as_lines("map", verbose=False):
        for _ in range(2):  # sigmas spanning too many orders for Cholesky: iSAM2 goes on with QR
            graph = slam.PoseGraph(NavNoise(), prior_sigmas=[1e3] * 6)
            for x in range(4):
                T = np.eye(4)
                T[0, 3] = x
                graph.add_submap(T, 600.0)
                graph.update()
        warnings.warn_explicit("a library's note", DeprecationWarning, np.__file__, 1)
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("vogjax map: warning: the pose graph's sigmas"), err
