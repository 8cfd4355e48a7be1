"""`vogjax view`: a map or a `vogjax map` report folder in the rerun 3D viewer."""

from __future__ import annotations

import sys
from pathlib import Path


def add_parser(commands) -> None:
    view = commands.add_parser(
        "view", help="show a map or report folder in the rerun viewer (pip install 'vogjax[view]')"
    )
    view.add_argument("path", type=Path, help="a report folder of `vogjax map` (DIR/<run> or DIR) or a map file (.vog)")
    view.add_argument(
        "--save",
        type=Path,
        default=None,
        help="write the recording to this .rrd file instead of opening a viewer (`rerun FILE.rrd` shows it)",
    )


def run(args) -> None:
    from vogjax.report.viewer import view

    try:
        logged = view(args.path, save=args.save)
    except RuntimeError as error:
        # rerun spawns its viewer from PATH ("Failed to find Rerun Viewer executable in PATH"):
        # with `.venv/bin/vogjax` run directly, the venv's bin (which holds `rerun`) is not on it
        if args.save is not None or "rerun" not in str(error).lower():
            raise
        first = (str(error).strip().splitlines() or [""])[0].strip()  # rerun goes on with install hints
        raise ValueError(
            f"cannot open the rerun viewer ({first}); write the recording with --save FILE.rrd "
            f"(`rerun FILE.rrd` shows it), or put {Path(sys.executable).parent} on PATH"
        ) from None
    boxes = sum(n for entity, n in logged.items() if entity.endswith("map/occupied"))
    where = f"wrote {args.save}" if args.save else "sent to the rerun viewer"
    print(f"{where}: {boxes} occupied voxels, entities: {', '.join(sorted(logged))}")
