"""`vogjax export`: a map file as an OctoMap tree (.bt, .ot) or a PLY cloud of occupied voxels."""

from __future__ import annotations

from pathlib import Path

FORMATS = ("bt", "ot", "ply")


def add_parser(commands) -> None:
    export = commands.add_parser("export", help="write a map as OctoMap .bt/.ot or a PLY point cloud")
    export.add_argument(
        "map", type=Path, help="map file (.vog: a VoxelMap, GlobalMap or ConfidenceMap, e.g. DIR/global_map.vog)"
    )
    export.add_argument(
        "--format",
        choices=FORMATS,
        default=None,
        help="bt: OctoMap max-likelihood, ot: OctoMap with every log-odds, ply: occupied voxel "
        "centres coloured by height (default: the suffix of --out)",
    )
    export.add_argument("--out", type=Path, required=True, help="file to write")


def run(args) -> None:
    from vogjax.io import octomap, ply
    from vogjax.io.voxels import VoxelSet, load_map

    format = args.format or args.out.suffix.lstrip(".").lower()
    if format not in FORMATS:
        raise ValueError(f"--format must be one of {', '.join(FORMATS)} (or --out must end in one), got {format!r}")
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
