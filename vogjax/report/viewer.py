"""A 3D look at a map or a `vogjax map` report folder in the rerun viewer (`pip install
'vogjax[view]'`), live or saved to an .rrd file (`rerun FILE.rrd` opens it later).

    vogjax.report.viewer.view("maps/propeller", save="propeller.rrd")

What is logged (entity paths):
- `map/occupied`: occupied voxels as boxes, viridis by height (static);
- `trajectory/navigation`, `trajectory/optimized`, `trajectory/truth` (whichever the folder's
  trajectories.csv holds): the submap base poses as a line strip, growing along the `submap`
  timeline (and `scan`, the submap's first scan), the newest base as a point;
- `loop_closures`: a line between the optimised bases of each accepted closure (from
  loop_closures.csv, columns i and k, when the folder has one), shown from submap k on;
- `timing/online_update_ms`, `timing/virtual_update_ms`, `timing/full_merge_update_ms`: the report's
  cumulative average update time per submap, on the `submap` timeline;
- `report`: the headline figures of report.json as text.
A folder holding several runs' folders (the `--out` of `vogjax map` for many runs) logs each under
its run name.
"""

from __future__ import annotations

import json
import os
import sys
from os import PathLike
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from vogjax.io.atomic import AtomicPath
from vogjax.io.ply import height_colours
from vogjax.io.voxels import VoxelSet, load_map

if TYPE_CHECKING:
    import rerun as rr

    from vogjax.maps import GlobalMap, VoxelMap
    from vogjax.maps.confidence import ConfidenceMap

TRAJECTORIES = {"navigation": (220, 60, 40), "optimized": (40, 110, 220), "truth": (120, 120, 120)}
CLOSURE_COLOUR = (40, 180, 60)


def rerun() -> ModuleType:
    """Import rerun, an optional dependency.

    Returns
    -------
    module
        The `rerun` module.

    Raises
    ------
    ValueError
        If rerun is not installed, naming the extra that installs it (``vogjax[view]``).
    """
    try:
        import rerun as rr
    except ImportError:
        raise ValueError("the viewer needs rerun: pip install 'vogjax[view]'") from None
    return rr


def view(path: str | PathLike, save: str | PathLike | None = None, spawn: bool | None = None) -> dict[str, int]:
    """Log a map file or a `vogjax map` report folder into a rerun recording.

    Parameters
    ----------
    path : str or os.PathLike
        A map file (.vog), a `vogjax map` run folder, or a folder of run folders (each logged
        under its run name).
    save : str or os.PathLike or None, optional
        An .rrd file to save the recording to (published atomically when complete).
    spawn : bool or None, optional
        Show the recording in a spawned viewer (None: when not saving).

    Returns
    -------
    dict of str to int
        What was logged: entity path -> number of items.

    Raises
    ------
    ValueError
        If `path` does not exist or is neither a map file nor a run folder, `save` does not
        end in .rrd, rerun is not installed, a viewer is to be spawned where there is no
        display, or a file of the folder cannot be read.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"path {str(path)!r} does not exist")
    runs = _runs(path)
    if save is not None:
        save = Path(save)
        if save.suffix != ".rrd":
            raise ValueError(f"--save must name an .rrd file, got {str(save)!r}")
    spawn = save is None if spawn is None else spawn
    if spawn and no_display():  # the viewer would start, open no window and log its failure
        raise ValueError(
            "cannot open the rerun viewer: no display (DISPLAY and WAYLAND_DISPLAY are unset); "
            "write the recording with --save FILE.rrd and open it with `rerun FILE.rrd` where there is one"
        )
    rr = rerun()
    recording = rr.RecordingStream("vogjax", recording_id=f"vogjax-{path.resolve()}")
    publication = None if save is None else AtomicPath(save)
    try:
        if publication is not None:
            recording.save(publication.temporary)
        if spawn:
            recording.spawn()
        logged = {}
        with recording:  # leaving it finalises the file
            recording.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
            for prefix, run in runs:
                if run.is_file():
                    logged.update(log_map(recording, load_map(run, device="cpu"), prefix))
                else:
                    logged.update(log_folder(recording, run, prefix))
    except BaseException:
        if publication is not None:
            publication.abort()
        raise
    if publication is not None:
        publication.commit()
    return logged


def no_display() -> bool:
    """Whether a window cannot open: on Linux (and the BSDs) a viewer needs an X or Wayland
    display; macOS and Windows always have one."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return False
    return not any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def _runs(path: Path) -> list[tuple[str, Path]]:
    """(entity prefix, map file or run folder) to log."""
    if path.is_file():
        return [("", path)]
    if (path / "global_map.vog").is_file():
        return [("", path)]
    runs = sorted(p for p in path.iterdir() if (p / "global_map.vog").is_file())
    if not runs:
        raise ValueError(f"path {str(path)!r} is neither a map file nor a `vogjax map` folder (no global_map.vog)")
    return [(run.name, run) for run in runs]


def _entity(prefix: str, name: str) -> str:
    return f"{prefix}/{name}" if prefix else name


def log_map(
    recording: rr.RecordingStream, source: VoxelMap | GlobalMap | ConfidenceMap | VoxelSet, prefix: str = ""
) -> dict[str, int]:
    """Log a map's occupied voxels as boxes coloured by height (viridis), static.

    Parameters
    ----------
    recording : rerun.RecordingStream
        The recording to log into.
    source : VoxelMap, GlobalMap, ConfidenceMap or VoxelSet
        The map.
    prefix : str, optional
        Entity path prefix (a run's name; "" for none).

    Returns
    -------
    dict of str to int
        ``{"PREFIX/map/occupied": number of boxes}``.
    """
    rr = rerun()
    voxels = source if isinstance(source, VoxelSet) else VoxelSet.from_map(source)
    centres = voxels.centres[voxels.state() == 2]
    entity = _entity(prefix, "map/occupied")
    recording.log(
        entity,
        rr.Boxes3D(
            centers=centres,
            half_sizes=np.full(3, voxels.voxel_size / 2),
            colors=height_colours(centres[:, 2]),
            fill_mode="solid",
        ),
        static=True,
    )
    return {entity: len(centres)}


def log_folder(recording: rr.RecordingStream, folder: Path, prefix: str = "") -> dict[str, int]:
    """Log a `vogjax map` run folder: map, trajectories, loop closures, per-submap timings, report.

    Parameters
    ----------
    recording : rerun.RecordingStream
        The recording to log into.
    folder : Path
        The run folder (global_map.vog, trajectories.csv, and loop_closures.csv and report.json
        where present).
    prefix : str, optional
        Entity path prefix (a run's name; "" for none).

    Returns
    -------
    dict of str to int
        What was logged: entity path -> number of items.

    Raises
    ------
    ValueError
        If a file of the folder is missing (the map, the trajectories) or cannot be read.
    """
    rr = rerun()
    logged = log_map(recording, load_map(folder / "global_map.vog", device="cpu"), prefix)
    table = read_trajectories(folder / "trajectories.csv")
    report = _read_report(folder / "report.json")
    closures = read_loop_closures(folder / "loop_closures.csv", len(table["submap"]))
    submaps = len(table["submap"])
    curves = (report or {}).get("timing_s", {}).get("curves", {})
    timing = {
        name: np.asarray(curves.get(f"{name}_s", []), dtype=np.float64) for name in ("online", "virtual", "full_merge")
    }
    for i in range(submaps):
        recording.set_time("submap", sequence=i)
        recording.set_time("scan", sequence=int(table["first_scan"][i]))
        for name, colour in TRAJECTORIES.items():
            if name not in table:
                continue
            entity = _entity(prefix, f"trajectory/{name}")
            recording.log(entity, rr.LineStrips3D([table[name][: i + 1]], colors=[colour], radii=0.02))
            recording.log(f"{entity}/base", rr.Points3D(table[name][i : i + 1], colors=[colour], radii=0.06))
            logged[entity] = i + 1
        if "optimized" in table:
            shown = closures[closures[:, 1] <= i]
            entity = _entity(prefix, "loop_closures")
            recording.log(entity, rr.LineStrips3D(table["optimized"][shown], colors=[CLOSURE_COLOUR], radii=0.015))
            logged[entity] = len(shown)
        for name, seconds in timing.items():
            if len(seconds) == submaps:
                entity = _entity(prefix, f"timing/{name}_update_ms")
                recording.log(entity, rr.Scalars(seconds[i] * 1e3))
                logged[entity] = i + 1
    if report is not None:
        entity = _entity(prefix, "report")
        recording.log(entity, rr.TextDocument(_summary(report), media_type=rr.MediaType.MARKDOWN), static=True)
        logged[entity] = 1
    return logged


def read_trajectories(path: Path) -> dict[str, npt.NDArray]:
    """Read a run folder's trajectories.csv.

    Parameters
    ----------
    path : Path
        The trajectories.csv `vogjax map` wrote.

    Returns
    -------
    dict of str to ndarray
        ``"submap"`` and ``"first_scan"``: (N,) int; and per trajectory present
        (``"navigation"``, ``"optimized"``, ``"truth"``) the (N, 3) float base positions, metres.

    Raises
    ------
    ValueError
        If the file cannot be read or lacks the submap and first_scan columns.
    """
    try:
        table = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
    except (OSError, ValueError) as error:
        raise ValueError(f"path {str(path)!r} cannot be read: {error}") from None
    names = table.dtype.names or ()
    if "submap" not in names or "first_scan" not in names:
        raise ValueError(f"path {str(path)!r} is not a trajectories.csv of `vogjax map` (columns: {names})")
    out = {"submap": table["submap"].astype(int), "first_scan": table["first_scan"].astype(int)}
    for name in TRAJECTORIES:
        columns = [f"{name}_{axis}" for axis in "xyz"]
        if all(c in names for c in columns):
            out[name] = np.stack([table[c] for c in columns], axis=1)
    return out


def read_loop_closures(path: Path, submaps: int) -> npt.NDArray[np.int_]:
    """Read the submap pairs of a run folder's loop_closures.csv.

    Parameters
    ----------
    path : Path
        The loop_closures.csv `vogjax map` wrote (absent: no closures).
    submaps : int
        The run's number of submaps; every id must lie below it.

    Returns
    -------
    (C, 2) ndarray of int
        Submap pairs (i, k) of the accepted closures (columns i and k; with a verdict column, the
        rows "accepted" only); (0, 2) when the file is absent.

    Raises
    ------
    ValueError
        If the file lacks columns i and k or names submaps outside 0 to ``submaps - 1``.
    """
    if not path.is_file():
        return np.zeros((0, 2), dtype=int)
    table = np.genfromtxt(path, delimiter=",", names=True, ndmin=1, dtype=None, encoding="utf-8")
    names = table.dtype.names or ()
    if "i" not in names or "k" not in names:
        raise ValueError(f"path {str(path)!r} needs columns i and k (submap ids), has {names}")
    if "verdict" in names:
        table = table[table["verdict"] == "accepted"]
    pairs = np.stack([table["i"], table["k"]], axis=1).astype(int).reshape(-1, 2)
    if len(pairs) and (pairs.min() < 0 or pairs.max() >= submaps):
        raise ValueError(f"path {str(path)!r} names submaps outside 0-{submaps - 1}")
    return pairs


def _read_report(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise ValueError(f"path {str(path)!r} is not a readable report: {error}") from None


def _summary(report: dict) -> str:
    closures = report.get("loop_closures", {})
    lines = [
        f"# {Path(str(report.get('run', ''))).stem}",
        "",
        f"- scans: {report.get('scans')}, submaps: {report.get('submaps')}",
        f"- loop closures: {closures.get('accepted')} accepted, {closures.get('rejected')} rejected",
    ]
    auc = {k: v for k, v in (report.get("auc") or {}).items() if v is not None}
    if auc:
        lines.append("- AUC: " + ", ".join(f"{k} {v:.3f}" for k, v in auc.items()))
    else:
        lines.append("- AUC: no ground truth")
    errors = {k: v for k, v in (report.get("trajectory_rmse_m") or {}).items() if v is not None}
    if errors:
        lines.append("- base-pose RMSE: " + ", ".join(f"{k} {v:.2f} m" for k, v in errors.items()))
    return "\n".join(lines)
