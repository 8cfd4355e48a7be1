"""`vogjax map`: reprocess recorded runs into maps, evaluate them, and write a report per run.

    reports = vj.report.map_runs(["run.h5"], "out", vj.config.JobConfig.from_toml("settings.toml"))

Per run, in DIR/<run name>/: global_map.vog, trajectories.csv, loop_closures.csv, TUM
trajectories (navigation.tum, optimized.tum, truth.tum), report.json and figures (top_view.png,
trajectory.png, roc.png, timing.png). Inputs, settings and the output folder are
checked before any work starts; a run's folder appears only once every file in it is written.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from os import PathLike
from pathlib import Path

from vogjax import pipeline, scenes
from vogjax.config import JobConfig, presets
from vogjax.io.atomic import AtomicPath, check_writable
from vogjax.io.dataset import Dataset
from vogjax.report import document, files, plots, timing
from vogjax.report.evaluate import evaluate_run


def map_runs(
    paths: Iterable[str | PathLike],
    out: str | PathLike,
    config: JobConfig | None = None,
    progress: bool = True,
    overwrite: bool = False,
    sensor_preset: str = "auto",
    given: Iterable[str] | None = None,
) -> list[dict]:
    """Map, evaluate and report each run: the `vogjax map` job.

    Every input is read and checked (scans, ground truth at the map's voxel size) and every
    output folder checked writable before any run is mapped; each run's folder appears only once
    every file in it is written. Kernel compilation is kept out of the timings. Each run is
    mapped with its sensor preset (`vogjax.config.presets.derive`: from its metadata, under the
    settings given), recorded in its report's ``preset``.

    Parameters
    ----------
    paths : iterable of str or os.PathLike
        Run files (.h5); no two with the same name (they would share an output folder).
    out : str or os.PathLike
        The output folder: run ``NAME.h5`` is written to ``out/NAME/`` (global_map.vog,
        trajectories, TUM files, report.json and figures).
    config : JobConfig or None, optional
        The job's settings (default: ``JobConfig()``).
    progress : bool, optional
        Show progress bars (on stderr).
    overwrite : bool, optional
        Replace a run's existing output folder; without it an existing one is an error, raised
        before any work.
    sensor_preset : str, optional
        "auto" (each run's preset from its metadata; a sonar run's is the defaults), "none"
        (`config` as it is) or a preset of `vogjax.config.presets.SENSORS`.
    given : iterable of str or None, optional
        The settings the caller set ("table.key"), kept over the preset's; None: those in
        `config` that differ from the defaults.

    Returns
    -------
    list of dict
        Each run's report, as written to its report.json (see the report.json reference).

    Raises
    ------
    ValueError
        If `config` is not a JobConfig, `sensor_preset` is not one of
        `vogjax.config.presets.CHOICES`, `paths` is empty or two runs share a name, a run's output
        folder exists and `overwrite` is not set, a run file is missing, damaged or empty, its
        scene's ground truth is refused at this voxel size, or an output folder cannot be
        written.
    """
    config, paths = check_job(paths, config)
    out = Path(out)
    for path in paths:
        refuse_existing(out / path.stem, overwrite)
    refuse_inputs_inside([out / path.stem for path in paths], paths)
    derived = []
    for path in paths:  # every input readable before any output is written
        with Dataset(path) as ds:
            if len(ds) == 0:
                raise ValueError(f"dataset {str(path)!r} holds no scans")
            ds.validate()
            derived.append(presets.derive(ds.metadata, config, given, sensor_preset))
            _check_ground_truth(ds, derived[-1].config)
    for path in paths:
        check_writable(out / path.stem, folder=True)
    reports = []
    for path, d in zip(paths, derived):
        try:
            reports.append(_map_into(path, out / path.stem, d, progress))
        except ValueError as error:  # of several runs, say which
            if str(path) in str(error):
                raise
            raise ValueError(f"run {str(path)!r}: {error}") from None
    return reports


def derive_settings(
    path: str | PathLike,
    config: JobConfig | None = None,
    sensor_preset: str = "auto",
    given: Iterable[str] | None = None,
) -> presets.Derived:
    """The settings a run is mapped with: `config` and its sensor preset (what `map_runs` uses).

    Parameters
    ----------
    path : str or os.PathLike
        The run file (.h5); only its metadata is read.
    config : JobConfig or None, optional
        The job's settings (default: ``JobConfig()``).
    sensor_preset : str, optional
        As `map_runs`'s.
    given : iterable of str or None, optional
        As `map_runs`'s.

    Returns
    -------
    vogjax.config.presets.Derived
        The settings, the preset, where each derived setting came from, and notes.

    Raises
    ------
    ValueError
        If the run file is missing or not a run file, `config` is not a JobConfig or
        `sensor_preset` is not one of `vogjax.config.presets.CHOICES`.
    """
    config, (path,) = check_job([path], config)
    with Dataset(path) as ds:
        return presets.derive(ds.metadata, config, given, sensor_preset)


def refuse_existing(out_dir: Path, overwrite: bool) -> None:
    """A ValueError when a run's output folder exists and `overwrite` is not set.

    Parameters
    ----------
    out_dir : Path
        The run's output folder.
    overwrite : bool
        Whether replacing it was asked for.
    """
    if out_dir.exists() and not overwrite:
        raise ValueError(f"out {str(out_dir)!r} exists (pass overwrite=True to replace it)")


def refuse_inputs_inside(folders: list[Path], inputs: list[Path], what: str = "run") -> None:
    """A ValueError when an input lies inside an output folder: replacing the folder (with
    overwrite) would delete it.

    Parameters
    ----------
    folders : list of Path
        The output folders.
    inputs : list of Path
        The files read (runs, a settings file).
    what : str, optional
        What the inputs are, for the message.
    """
    for folder in folders:
        resolved = folder.resolve()
        for path in inputs:
            if path.resolve().is_relative_to(resolved):
                raise ValueError(
                    f"{what} {str(path)!r} lies inside the output folder {str(folder)!r}, which mapping "
                    "replaces: move it, or choose another out"
                )


def check_job(paths, config) -> tuple[JobConfig, list[Path]]:
    """The job's settings and run paths, checked: a JobConfig, at least one run, no two runs
    writing the same output folder."""
    config = config or JobConfig()
    if not isinstance(config, JobConfig):
        raise ValueError(f"config must be a JobConfig, got {type(config).__name__}")
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("paths must name at least one run file")
    names = [p.stem for p in paths]
    if len(set(names)) != len(names):
        raise ValueError(f"paths: two runs would share an output folder: {names}")
    return config, paths


def _check_ground_truth(ds: Dataset, config: JobConfig) -> None:
    """The ground truth of the run's scene (if it names a built-in one) at the map's voxel size
    is refused now if it would be, not after the pipeline has run."""
    name = ds.metadata.get("scene")
    if name in scenes.NAMES:
        scenes.load(name).check_occupancy(config.pipeline.map.voxel_size)


def map_run(
    path: str | PathLike,
    out_dir: str | PathLike,
    config: JobConfig | None = None,
    progress: bool = True,
    overwrite: bool = False,
    sensor_preset: str = "auto",
    given: Iterable[str] | None = None,
) -> dict:
    """Map, evaluate and report one run into a folder of its own.

    Parameters
    ----------
    path : str or os.PathLike
        The run file (.h5).
    out_dir : str or os.PathLike
        The folder to write; with `overwrite`, an existing one is replaced only once everything
        is written.
    config : JobConfig or None, optional
        The job's settings (default: ``JobConfig()``).
    progress : bool, optional
        Show progress bars (on stderr).
    overwrite : bool, optional
        Replace an existing `out_dir`; without it that is an error, raised before any work.
    sensor_preset : str, optional
        As `map_runs`'s.
    given : iterable of str or None, optional
        As `map_runs`'s.

    Returns
    -------
    dict
        The run's report, as written to out_dir/report.json.

    Raises
    ------
    ValueError
        If `config` is not a JobConfig, `out_dir` exists and `overwrite` is not set, the run file
        is missing or not a run file, its scene's
        ground truth is refused at this voxel size, `out_dir` cannot be written, or the run is
        found damaged while it is mapped.
    """
    config, (path,) = check_job([path], config)
    refuse_existing(Path(out_dir), overwrite)
    refuse_inputs_inside([Path(out_dir)], [path])
    with Dataset(path) as ds:
        derived = presets.derive(ds.metadata, config, given, sensor_preset)
        _check_ground_truth(ds, derived.config)
    check_writable(out_dir, folder=True)
    return _map_into(path, Path(out_dir), derived, progress)


def _map_into(path: Path, out_dir: Path, derived: presets.Derived, progress: bool) -> dict:
    config = derived.config
    warm_up_s = pipeline.warm_up(config.pipeline)  # compilation kept out of the timings
    with Dataset(path) as ds:
        start = time.perf_counter()
        result = pipeline.run(ds, config.pipeline, progress)
        pipeline_s = time.perf_counter() - start
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with AtomicPath(out_dir, folder=True) as folder:
        return _evaluate_and_write(result, path, pipeline_s, warm_up_s, derived, folder, progress)


def _evaluate_and_write(
    result, path: Path, pipeline_s: float, warm_up_s: float, derived: presets.Derived, folder: Path, progress: bool
) -> dict:
    config = derived.config
    name = result.metadata.get("scene")
    scene = scenes.load(name) if name in scenes.NAMES else None
    metrics, roc = evaluate_run(result, scene, config.report.surface_points) if scene else ({}, {})
    curves = timing.curves(result)
    report = document.build(result, path, metrics, curves, pipeline_s, config)
    report["timing_s"]["warm_up"] = warm_up_s
    report["preset"] = derived.to_dict()
    # 1. the map and the trajectories
    result.global_map.save(folder / "global_map.vog")
    if result.confidence_map is not None:
        result.confidence_map.save(folder / "confidence_map.vog")
    files.save_trajectories(result, folder / "trajectories.csv")
    files.save_loop_closures(result, folder / "loop_closures.csv")
    files.save_tum_trajectories(result, folder)
    # 2. figures
    centres, log_odds = result.global_map.voxels()
    counts = f"{result.vog.num_submaps} submaps, {len(result.loop_closures)} loop closures"
    plots.top_view(
        centres,
        log_odds,
        result.config.map,
        folder / "top_view.png",
        title=f"{path.stem}: the online global map from above\n{counts}",
        scene=scene,
    )
    plots.trajectories(result, folder / "trajectory.png", title=f"{path.stem}: vehicle path from above\n{counts}")
    if roc:
        voxels = metrics.get("evaluated_voxels", 0)
        scored = (
            f"Scored over the {voxels:,} ground-truth voxels the online or standard map observed "
            "(the registered curve: those the registered online or the standard map observed)."
        )
        plots.roc_curves(roc, folder / "roc.png", title=f"{path.stem}: occupancy vs ground truth (ROC)", note=scored)
    if curves is not None:
        plots.timing(
            curves, folder / "timing.png", title=f"{path.stem}: update and query times on {result.global_map.device}"
        )
    # 3. the report last: its presence says the rest is there
    report = document.finite_or_null(report)  # what is returned is what is written: null, not NaN
    (folder / "report.json").write_text(json.dumps(report, indent=2, default=document.json_default, allow_nan=False))
    return report
