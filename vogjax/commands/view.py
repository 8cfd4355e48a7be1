"""`vogjax view`: a map or a `vogjax map` report folder in the rerun 3D viewer."""

from __future__ import annotations

from pathlib import Path


def add_parser(commands) -> None:
    view = commands.add_parser("view", help="show a map or report folder in the rerun viewer "
                                            "(pip install 'vogjax[view]')")
    view.add_argument("path", type=Path,
                      help="a report folder of `vogjax map` (DIR/<run> or DIR) or a map file (.vog)")
    view.add_argument("--save", type=Path, default=None,
                      help="write the recording to this .rrd file instead of opening a viewer "
                           "(`rerun FILE.rrd` shows it)")


def run(args) -> None:
    from vogjax.report.viewer import view

    logged = view(args.path, save=args.save)
    boxes = sum(n for entity, n in logged.items() if entity.endswith("map/occupied"))
    where = f"wrote {args.save}" if args.save else "sent to the rerun viewer"
    print(f"{where}: {boxes} occupied voxels, entities: {', '.join(sorted(logged))}")
