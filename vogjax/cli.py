"""The `vogjax` command."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="vogjax", description="GPU/JAX occupancy mapping")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="map a built-in scene from simulated sonar scans")
    demo.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    demo.add_argument("--scans", type=int, default=3000, help="number of sonar scans")
    demo.add_argument("--device", default=None, help="Warp device (default: CUDA if present)")
    args = parser.parse_args(argv)
    if args.command == "demo":
        if args.scans < 1:
            parser.error("--scans must be at least 1")
        from vogjax import demo as demo_module

        demo_module.run(args.out, args.scans, args.device)
    return 0


if __name__ == "__main__":
    sys.exit(main())
