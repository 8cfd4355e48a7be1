"""The command line as a user meets it (issue 34): `--version`, every subcommand's help (a
description, defaults, choices and examples that parse), `vogjax config` (a settings file of
every default that `--config` reads back to the defaults), one-line errors naming the flag or
file with exit 2, `vogjax map` keeping an existing output without --overwrite, and nothing but
results on stdout."""

from __future__ import annotations

import argparse
import dataclasses
import errno
import os
import shlex
import subprocess
import sys
import tempfile
import tomllib
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.config import JobConfig
from vogjax.config.planner import ExploreConfig, PlannerConfig
from vogjax.config.schema import rule_of

TINY = "[timing]\nrays = 100\nevery_submaps = 0\n[report]\nsurface_points = 500\n[pipeline]\nscans_per_submap = 10\n"


def help_of(capsys, *argv) -> str:
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*argv, "--help"])
    assert exit_info.value.code == 0
    return capsys.readouterr().out


def refused(capsys, argv) -> str:
    """The one stderr line of a command refused with exit 2 (and nothing on stdout)."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main([str(a) for a in argv])
    assert exit_info.value.code == 2
    out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert out == ""
    return lines[0]


def leaves(config) -> dict:
    """Every plain setting of a Config tree, by its dotted path of field names."""
    out = {}
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if rule_of(field).kind == "section":
            out.update({f"{field.name}.{k}": v for k, v in leaves(value).items()})
        else:
            out[field.name] = value
    return out


def document_leaves(document: dict, prefix: str = "") -> list[str]:
    """Every key of a parsed TOML document that holds a value, dotted."""
    keys = []
    for key, value in document.items():
        if isinstance(value, dict):
            keys += document_leaves(value, f"{prefix}{key}.")
        else:
            keys.append(prefix + key)
    return keys


# ------------------------------------------------------------------------------ version and help


def test_version_comes_from_the_package_metadata(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"vogjax {metadata.version('vogjax')}"
    assert vj.__version__ == metadata.version("vogjax")
    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert vj.__version__ == pyproject["project"]["version"]


@pytest.mark.parametrize("command", list(cli.COMMANDS))
def test_every_subcommand_has_a_description_defaults_and_examples_that_parse(capsys, command):
    text = help_of(capsys, command)
    usage, _, rest = text.partition("\n\n")
    description = rest.split("\n\n")[0]
    assert len(description.split()) >= 30, f"{command}: no description paragraph"
    assert "\nexamples:\n" in text
    examples = [line.strip() for line in text.split("\nexamples:\n")[1].splitlines() if line.strip()]
    assert examples and all(line.startswith(f"vogjax {command}") for line in examples)
    parser = cli.build_parser()
    for line in examples:  # each example is a command the parser accepts
        args = parser.parse_args(shlex.split(line.split(" > ")[0], comments=True)[1:])
        assert args.command == command
    assert "--verbose" in text and "--quiet" in text
    # every option says its default: shown after its help, or (None: derived) said in it
    flat = " ".join(text.split())
    subparser = cli._subparser(parser, command)
    for action in subparser._actions:
        if not action.option_strings or action.required or action.default is argparse.SUPPRESS:
            continue
        if action.default is None:
            if any(action in group._group_actions for group in subparser._mutually_exclusive_groups if group.required):
                continue  # one of a required choice (config --defaults | --check)
            assert "default" in action.help, f"{command} {action.option_strings[0]}: no word on its default"
        elif action.default is not False:
            assert f"(default: {action.default})" in flat, f"{command} {action.option_strings[0]}"


def test_help_shows_defaults_and_lists_choices_in_the_usage(capsys):
    simulate = help_of(capsys, "simulate")
    assert "--scene {propeller,pilings,tank,boxes,warehouse}" in " ".join(simulate.split())
    assert "--sensor {sonar,lidar}" in " ".join(simulate.split())
    assert "range noise (Gaussian), metres (default: 0.02)" in " ".join(simulate.split())
    assert "(default: 0)" in simulate  # --seed
    demo = " ".join(help_of(capsys, "demo").split())
    assert "(default: demo_out)" in demo and "(default: 2)" in demo and "(default: propeller)" in demo
    mapping = " ".join(help_of(capsys, "map").split())
    assert "--preset {default,paper}" in mapping and "vogjax config --defaults" in mapping
    assert "see README" not in mapping
    top = " ".join(help_of(capsys).split())
    assert all(name in top for name in cli.COMMANDS) and "--version" in top


def test_build_parser_runs_nothing(tmp_path):
    """The reference pages are generated from `build_parser()`: it prints nothing, writes
    nothing, and starts neither Warp nor JAX."""
    script = (
        "import sys; from vogjax.cli import build_parser; p = build_parser(); "
        "import warp._src.context as c; "
        "print(type(p).__name__, c.runtime is None, 'jax' in sys.modules, 'mujoco' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path, check=True)
    assert done.stdout.split() == ["Parser", "True", "False", "False"]
    assert done.stderr == "" and list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ vogjax config


def defaults(capsys, *argv) -> str:
    assert cli.main(["config", "--defaults", *argv]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    return out


@pytest.mark.parametrize("preset", ["default", "paper"])
def test_config_defaults_round_trip_for_map(tmp_path, capsys, preset):
    text = defaults(capsys, "--preset", preset)
    path = tmp_path / "settings.toml"
    path.write_text(text)
    expected = JobConfig.preset(preset)
    assert JobConfig.from_toml(path) == expected  # read as `vogjax map --config` reads it
    assert JobConfig.from_toml(path, JobConfig.preset("paper")) == expected
    # every setting is in the file, with what it accepts
    document = tomllib.loads(text)
    assert len(document_leaves(document)) == len(leaves(expected))
    assert "voxel_size = 0.1" in text and "positive number >= 0.0001 and <= 1000, in m" in text
    assert "scans_per_submap = 100 " in text or "scans_per_submap = 200 " in text
    assert '"covariance" or a positive integer >= 2' in text
    assert all(len(line) <= 100 for line in text.splitlines())
    # a value changed in the file is read as changed
    path.write_text(text.replace("voxel_size = 0.1 ", "voxel_size = 0.2 "))
    assert JobConfig.from_toml(path).pipeline.map.voxel_size == 0.2
    assert cli.main(["config", "--check", str(path), "--preset", preset]) == 0
    assert capsys.readouterr().out.splitlines()[1:] == ["  map.voxel_size = 0.2"]


def test_config_defaults_round_trip_for_explore(tmp_path, capsys):
    from vogjax.sim.explore import load_settings, scene_planner

    path = tmp_path / "explore.toml"
    path.write_text(defaults(capsys, "--for", "explore"))  # the time-aware rule: one planner for all scenes
    for scene in vj.scenes.NAMES:
        assert load_settings(path, scene, 3) == load_settings(None, scene, 3)
    document = tomllib.loads(path.read_text())
    assert len(document_leaves(document)) == len(leaves(ExploreConfig()))
    path.write_text(defaults(capsys, "--for", "explore", "--rule", "papers"))
    for scene in vj.scenes.NAMES:  # the commented [planner] leaves each scene's own papers' settings
        assert load_settings(path, scene, 3, "papers") == load_settings(None, scene, 3, "papers")
    assert len(document_leaves(tomllib.loads(path.read_text()))) == len(leaves(ExploreConfig().pipeline))
    path.write_text(defaults(capsys, "--for", "explore", "--rule", "papers", "--scene", "tank"))
    assert load_settings(path, "tank", 3, "papers") == load_settings(None, "tank", 3, "papers")
    edge_m = tomllib.loads(path.read_text())["planner"]["edge_length_m"]
    assert edge_m == scene_planner("tank", rule="papers").edge_length_m != PlannerConfig().edge_length_m
    assert cli.main(["config", "--check", str(path), "--for", "explore", "--rule", "papers", "--scene", "tank"]) == 0
    assert "every setting at its default" in capsys.readouterr().out


def test_config_check_names_the_setting_at_fault(tmp_path, capsys):
    path = tmp_path / "typo.toml"
    path.write_text("[map]\nvoxel_sise = 0.1\n")
    line = refused(capsys, ["config", "--check", path])
    assert "map.voxel_sise" in line and "did you mean voxel_size?" in line
    path.write_text("[loop_closure.icp]\nmax_iterations = 0\n")
    assert "loop_closure.icp.max_iterations" in refused(capsys, ["config", "--check", path])
    assert "nope.toml" in refused(capsys, ["config", "--check", tmp_path / "nope.toml"])


# ------------------------------------------------------------------------------ user errors


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A folder with a small run, a map, a settings file with a typo and a text file."""
    root = tmp_path_factory.mktemp("cli_help")
    assert cli.main(["simulate", "--scene", "boxes", "--scans", "25", "--out", str(root / "run.h5"), "-q"]) == 0
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, max_range=5.0), device="cpu")
    vmap.integrate_scan(np.zeros(3), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    vmap.save(root / "map.vog")
    (root / "typo.toml").write_text("[map]\nvoxel_sise = 0.1\n")
    (root / "tiny.toml").write_text(TINY)
    (root / "notes.txt").write_text("not a run\n")
    (root / "nostd.toml").write_text("[pipeline]\nstandard_map = false\n")
    return root


# (arguments, what the line must say, what it must not say); {d}: the files' folder
ERRORS = [
    ("simulate --scene boxes --scans -5 --out {d}/x.h5", ["--scans", "positive integer"], ["num_scans"]),
    ("simulate --scene boxes --scans x --out {d}/x.h5", ["--scans", "'x'"], []),
    ("simulate --scene boxes --scans 100000000 --out {d}/x.h5", ["--scans", "at most"], ["num_scans"]),
    ("simulate --scene boxes --outt {d}/x.h5", ["unknown flag --outt", "did you mean --out?"], ["required"]),
    ("simulate --scene boxs --out {d}/x.h5", ["--scene", "did you mean boxes?"], []),
    ("simulate --scene boxes --out {d}/run.h5", ["--out", "run.h5", "--overwrite"], ["overwrite=True"]),
    ("simulate --scene boxes --out {d}", ["--out", "is a folder"], []),
    ("simulate --scene boxes --out /proc/x.h5", ["/proc", "takes no new files"], ["No such file or directory'"]),
    ("simulate --scene boxes --out {d}/missing/x.h5", ["missing", "does not exist"], []),
    ("simulate --scene boxes --out {d}/notes.txt/x.h5", ["notes.txt", "is a file, not a folder"], []),
    ("simulate --scene boxes --laps 0 --out {d}/x.h5", ["--laps"], []),
    ("simulate --scene boxes --seed -1 --out {d}/x.h5", ["--seed"], []),
    ("simulate --scene boxes --range-noise nan --out {d}/x.h5", ["--range-noise"], []),
    ("simulate --scene boxes --out {d}/x.h5 --quiet --verbose", ["--verbose", "--quiet"], []),
    ("simulate --scene boxes --out {d}/x.h5 extra", ["unexpected argument 'extra'"], []),
    ("map {d}/run.h5 --outt {d}/maps", ["unknown flag --outt", "did you mean --out?"], []),
    ("map {d}/run.h5", ["--out"], []),
    ("map {d}/nope.h5 --out {d}/maps", ["nope.h5"], []),
    ("map {d}/notes.txt --out {d}/maps", ["notes.txt"], []),
    ("map {d}/run.h5 --out {d}/maps --config {d}/typo.toml", ["voxel_sise", "did you mean voxel_size?"], []),
    ("map {d}/run.h5 --out {d}/maps --config {d}/nope.toml", ["nope.toml"], []),
    ("map {d}/run.h5 --out {d}/maps --preset fast", ["--preset", "'fast'"], []),
    ("map {d}/run.h5 --out {d}/maps --workers 0", ["--workers"], []),
    ("map {d}/run.h5 --out {d}/notes.txt", ["notes.txt"], []),
    ("explore --scene boxes --submaps 0 --out {d}/e.h5", ["--submaps"], []),
    ("explore --scene boxes --submaps 2 --seed -1 --out {d}/e.h5", ["--seed"], []),
    ("explore --scene boxes --submaps 2 --map octomap --out {d}/e.h5", ["--map", "octomap"], []),
    ("explore --scene boxes --submaps 2 --out {d}/run.h5", ["--out", "run.h5", "--overwrite"], ["overwrite=True"]),
    (
        "explore --scene boxes --submaps 2 --map standard --config {d}/nostd.toml --out {d}/e.h5",
        ["--map standard", "standard_map"],
        ["map_kind"],
    ),
    ("demo --laps 0 --out {d}/demo", ["--laps"], []),
    ("demo --scene nope --out {d}/demo", ["--scene", "nope"], []),
    ("export {d}/map.vog --format plyy --out {d}/m.bt", ["--format", "did you mean ply?"], []),
    ("export {d}/map.vog --format xyz --out {d}/m.bt", ["--format", "choose from bt, ot, ply"], ["did you mean"]),
    ("export {d}/map.vog --out {d}/m.txt", ["--format", "--out"], []),
    ("export {d}/nope.vog --out {d}/m.bt", ["nope.vog"], []),
    ("export {d}/map.vog --out {d}/missing/m.bt", ["missing"], []),
    ("import {d}/nope.bag --points /p --odometry /o --out {d}/i.h5", ["nope.bag"], []),
    ("import {d}/notes.txt --points /p --odometry /o --max-range -1 --out {d}/i.h5", ["--max-range"], []),
    ("import {d}/notes.txt --points /p --odometry /o --out {d}/run.h5", ["--out", "--overwrite"], []),
    ("view {d}/map.vog --save {d}/x.txt", ["--save", "x.txt"], []),
    ("view {d}/nope.vog", ["nope.vog"], []),
    ("config --defaults --scene tank", ["--scene", "--for explore"], []),
    ("config --defaults --for explore --scene tank", ["--scene", "--rule papers"], []),
    ("config", ["--defaults", "--check"], []),
    ("mapp", ["unknown command 'mapp'", "did you mean map?"], []),
    ("", ["no command given", "simulate"], []),
    ("--outt", ["unknown flag --outt"], []),
]


@pytest.mark.parametrize("argv, says, never", ERRORS, ids=[e[0].replace("{d}/", "") or "(none)" for e in ERRORS])
def test_every_user_error_is_one_line_naming_the_flag_or_file(files, capsys, argv, says, never):
    before = sorted(p.name for p in files.iterdir())
    line = refused(capsys, shlex.split(argv.format(d=files)))
    assert line.startswith("vogjax") and ": error: " in line
    for words in says:
        assert words in line, line
    for words in never:
        assert words not in line, line
    assert sorted(p.name for p in files.iterdir()) == before  # refused before any work


def test_a_read_only_or_locked_folder_says_so(files, capsys, monkeypatch):
    """Root passes permission bits, so the two refusals are provoked where they are found."""

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
    line = refused(capsys, ["simulate", "--scene", "boxes", "--out", files / "x.h5"])
    assert str(files) in line and "read-only file system" in line
    monkeypatch.undo()
    monkeypatch.setattr(os, "access", lambda *args, **kwargs: False)
    line = refused(capsys, ["simulate", "--scene", "boxes", "--out", files / "x.h5"])
    assert "not writable (permission denied)" in line


# ------------------------------------------------------------------------------ vogjax map and --overwrite


def test_map_keeps_an_existing_output_unless_overwrite(files, tmp_path, capsys):
    out = tmp_path / "maps"
    (out / "run").mkdir(parents=True)
    (out / "run" / "mine.txt").write_text("an earlier result")
    argv = ["map", files / "run.h5", "--out", out, "--config", files / "tiny.toml", "--quiet"]
    line = refused(capsys, argv)
    assert str(out / "run") in line and "--overwrite" in line
    assert [p.name for p in (out / "run").iterdir()] == ["mine.txt"]
    with pytest.raises(ValueError, match="overwrite=True"):  # the library keeps it too
        vj.report.map_runs([files / "run.h5"], out, JobConfig.from_toml(files / "tiny.toml"), progress=False)
    assert cli.main([str(a) for a in argv] + ["--overwrite"]) == 0
    printed = capsys.readouterr().out
    assert "AUC online" in printed and max(len(line) for line in printed.splitlines()) <= 100
    assert (out / "run" / "report.json").is_file() and not (out / "run" / "mine.txt").exists()


# ------------------------------------------------------------------------------ stdout and library noise


def test_stdout_carries_results_only_and_warp_speaks_only_when_asked(tmp_path):
    """A fresh process each (Warp prints its CUDA-driver warning at start-up, once)."""
    vogjax = [sys.executable, "-m", "vogjax.cli"]
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, max_range=5.0), device="cpu")
    vmap.integrate_scan(np.zeros(3), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    vmap.save(tmp_path / "map.vog")
    quiet = subprocess.run(  # a command that starts Warp (the map's arrays) and prints its result
        [*vogjax, "export", str(tmp_path / "map.vog"), "--out", str(tmp_path / "a.bt")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stdout.splitlines() == [quiet.stdout.strip()] and quiet.stdout.startswith("wrote ")
    assert "Warp" not in quiet.stderr and "CUDA" not in quiet.stderr
    verbose = subprocess.run(
        [*vogjax, "simulate", "--scene", "boxes", "--scans", "5", "--out", str(tmp_path / "b.h5"), "--verbose"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert verbose.returncode == 0, verbose.stderr
    assert verbose.stdout.startswith("wrote ") and len(verbose.stdout.splitlines()) == 1
    warnings = [line for line in verbose.stderr.splitlines() if cli.CUDA_DRIVER_WARNING in line]
    assert len(warnings) <= 1  # none on a machine with a driver
    if warnings:  # on a line of its own, before the progress bar
        assert verbose.stderr.index(cli.CUDA_DRIVER_WARNING) < verbose.stderr.index("simulating boxes")
        assert verbose.stderr.startswith(warnings[0])
    exported = subprocess.run(
        [*vogjax, "export", str(tmp_path / "missing.vog"), "--out", str(tmp_path / "m.bt")],
        capture_output=True,
        text=True,
    )
    assert exported.returncode == 2 and exported.stdout == ""
    assert [line for line in exported.stderr.splitlines() if line.strip()] == [
        exported.stderr.strip()
    ] and "missing.vog" in exported.stderr
