"""`vogjax view`: a map or a `vogjax map` report folder in the rerun 3D viewer."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from vogjax.commands.common import add_output_flags

DESCRIPTION = """\
Show a map or a `vogjax map` report folder in the rerun 3D viewer (pip install
'vogjax[view]'): the occupied voxels as boxes coloured by height, and for a report folder the
trajectories (truth, navigation, optimised), the submap base poses and the loop closures. With
--save the recording is written to an .rrd file instead (replaced if it exists), to open later
with `rerun FILE.rrd` or on another machine."""

EPILOG = """\
examples:
  vogjax view maps/boxes
  vogjax view maps/boxes/global_map.vog --save boxes.rrd"""


def add_parser(commands) -> None:
    """Declare `vogjax view` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    view = commands.add_parser(
        "view",
        help="show a map or report folder in the rerun viewer (pip install 'vogjax[view]')",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    view.add_argument("path", type=Path, help="a report folder of `vogjax map` (DIR/<run> or DIR) or a map file (.vog)")
    view.add_argument(
        "--save",
        type=Path,
        default=None,
        metavar="FILE.rrd",
        help="write the recording to this .rrd file (`rerun FILE.rrd` shows it; default: open a viewer)",
    )
    add_output_flags(view)


def run(args) -> None:
    """Send the map to the viewer (or the .rrd file) and print what was logged.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax view`.
    """
    from vogjax.report import viewer

    try:
        logged = viewer.view(args.path, save=args.save)
    except RuntimeError as error:
        if args.save is not None or "rerun" not in str(error).lower():
            raise
        reap_viewers()
        first = (str(error).strip().splitlines() or [""])[0].strip()  # rerun goes on with install hints
        # rerun spawns its viewer from PATH ("Failed to find Rerun Viewer executable in PATH"):
        # with `.venv/bin/vogjax` run directly, the venv's bin (which holds `rerun`) is not on it
        on_path = f", or put {Path(sys.executable).parent} on PATH" if "PATH" in str(error) else ""
        raise ValueError(
            f"cannot open the rerun viewer ({first}); write the recording with --save FILE.rrd "
            f"(`rerun FILE.rrd` shows it){on_path}"
        ) from None
    boxes = sum(n for entity, n in logged.items() if entity.endswith("map/occupied"))
    where = f"wrote {args.save}" if args.save else "sent to the rerun viewer"
    print(f"{where}: {boxes} occupied voxels, entities: {', '.join(sorted(logged))}")


def reap_viewers() -> None:
    """Wait for this process's exited `rerun` children (Linux): rerun spawns its viewer without
    handing back its pid, and one that failed would stay a zombie (a defunct process) until
    vogjax exits, or after it where the container's init reaps nothing."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            pid, rest = stat.read_text().split(" (", 1)
            name, fields = rest.rsplit(") ", 1)
            state, parent = fields.split()[:2]
        except (OSError, ValueError):  # gone meanwhile
            continue
        if name == "rerun" and state == "Z" and int(parent) == os.getpid():
            try:
                os.waitpid(int(pid), 0)
            except ChildProcessError:  # reaped meanwhile
                pass
