"""`vogjax export`: a map file as an OctoMap tree (.bt, .ot) or a PLY cloud of occupied voxels."""

from __future__ import annotations

from pathlib import Path

from vogjax.commands.common import add_output_flags, refuse_replacing_input

FORMATS = ("bt", "ot", "ply")

DESCRIPTION = """\
Write a map file as an OctoMap tree or a point cloud, for tools outside vogjax: .bt (OctoMap's
binary max-likelihood tree: occupied or free per leaf, as octovis and ROS's octomap_server read
it), .ot (OctoMap's full tree with every voxel's log-odds) or .ply (the occupied voxels' centres,
coloured by height, for CloudCompare or MeshLab). The map is a .vog file: a report folder's
global_map.vog or confidence_map.vog, or one saved from Python. An existing --out is replaced."""

EPILOG = """\
examples:
  vogjax export maps/boxes/global_map.vog --out boxes.bt
  vogjax export maps/boxes/global_map.vog --format ply --out boxes_occupied.ply"""


def add_parser(commands) -> None:
    """Declare `vogjax export` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    export = commands.add_parser(
        "export",
        help="write a map as OctoMap .bt/.ot or a PLY point cloud",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    export.add_argument(
        "map",
        type=Path,
        metavar="MAP.vog",
        help="map file (.vog: a VoxelMap, GlobalMap or ConfidenceMap, e.g. DIR/global_map.vog)",
    )
    export.add_argument(
        "--format",
        choices=FORMATS,
        default=None,
        help="bt: OctoMap max-likelihood, ot: OctoMap with every log-odds, ply: occupied voxel "
        "centres coloured by height (default: the suffix of --out)",
    )
    export.add_argument("--out", type=Path, required=True, metavar="FILE", help="file to write (.bt, .ot or .ply)")
    add_output_flags(export)


def run(args) -> None:
    """Export the map and print what was written.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax export`.
    """
    from vogjax.io import octomap, ply
    from vogjax.io.voxels import VoxelSet, load_map

    implied = args.out.suffix.lstrip(".").lower()  # readers go by the suffix: a .bt must hold a bt tree
    if args.format is not None and implied in FORMATS and implied != args.format:
        raise ValueError(f"--format {args.format} contradicts --out {str(args.out)!r} (a .{implied} file)")
    format = args.format or implied
    if format not in FORMATS:
        raise ValueError(f"--format must be one of {', '.join(FORMATS)} (or --out must end in one), got {format!r}")
    refuse_replacing_input(args.out, args.map, "map being exported")
    voxels = VoxelSet.from_map(load_map(args.map, device="cpu"))
    if format == "ply":
        count = ply.save(voxels, args.out)
        print(f"wrote {args.out}: {count} occupied voxels of {len(voxels)} observed")
    else:
        nodes = octomap.save(voxels, args.out, format)
        print(
            f"wrote {args.out}: OctoMap {format} tree of {nodes} nodes, {len(voxels)} observed voxels, "
            f"resolution {voxels.voxel_size} m"
        )
