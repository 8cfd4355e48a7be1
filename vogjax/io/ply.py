"""PLY point clouds of a map's occupied voxels, coloured by height (MeshLab, CloudCompare,
Blender, Open3D, trimesh read them).

    vogjax.io.ply.save(global_map, "occupied.ply")    # or a VoxelSet

One vertex per occupied voxel: its centre (x, y, z, metres: float32, or float64 where float32
would move a centre by more than COORDINATE_TOLERANCE voxels, far from the origin), an RGB
colour from the viridis colour map over the occupied voxels' height range (low: purple, high:
yellow) and its occupancy probability (float32 `probability`). Binary little-endian; comments
record the voxel size and the height range of the colours.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vogjax.io.atomic import AtomicPath
from vogjax.io.voxels import VoxelSet

# Centres rounded to float32 may move by this many voxels at most; beyond (at 0.1 m voxels from
# about 4 km out) they are written as float64.
COORDINATE_TOLERANCE = 1e-3


def vertex_dtype(coordinate: str) -> np.dtype:
    """The structured dtype of one PLY vertex.

    Parameters
    ----------
    coordinate : str
        NumPy dtype of x, y, z: "<f4" or "<f8".

    Returns
    -------
    numpy.dtype
        Fields x, y, z, red, green, blue (uint8) and probability (float32).
    """
    return np.dtype(
        [
            ("x", coordinate),
            ("y", coordinate),
            ("z", coordinate),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
            ("probability", "<f4"),
        ]
    )


def height_colours(z: npt.ArrayLike, low: float | None = None, high: float | None = None) -> npt.NDArray[np.uint8]:
    """Viridis colours of heights (low: purple, high: yellow).

    Parameters
    ----------
    z : (K,) array_like of float
        Heights, metres.
    low, high : float or None, optional
        The heights the colour map spans (default: the range of `z`); heights outside it take
        the end colours, and a span of zero the middle colour.

    Returns
    -------
    (K, 3) ndarray of uint8
        RGB colours.
    """
    from matplotlib import colormaps

    z = np.asarray(z, dtype=np.float64)
    if len(z) == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    low = float(z.min()) if low is None else low
    high = float(z.max()) if high is None else high
    scaled = (z - low) / (high - low) if high > low else np.full(len(z), 0.5)
    return np.round(colormaps["viridis"](np.clip(scaled, 0.0, 1.0))[:, :3] * 255).astype(np.uint8)


def save(source: Any, path: str | PathLike) -> int:
    """Write the occupied voxels of a map as a binary PLY point cloud, published atomically.

    Parameters
    ----------
    source : VoxelMap, GlobalMap, ConfidenceMap or VoxelSet
        The map (a confidence-rich map by its mean occupancy).
    path : str or os.PathLike
        The file to write (replaced if it exists).

    Returns
    -------
    int
        How many vertices (occupied voxels) were written.

    Raises
    ------
    ValueError
        If `source` is no map `VoxelSet.from_map` reads, or `path` cannot be written.
    """
    voxels = source if isinstance(source, VoxelSet) else VoxelSet.from_map(source)
    occupied = voxels.state() == 2
    centres = voxels.centres[occupied]
    rounded = np.abs(centres.astype(np.float32) - centres).max(initial=0.0)
    vertex = vertex_dtype("<f4" if rounded <= COORDINATE_TOLERANCE * voxels.voxel_size else "<f8")
    vertices = np.zeros(len(centres), dtype=vertex)
    for axis, name in enumerate("xyz"):
        vertices[name] = centres[:, axis]
    colours = height_colours(centres[:, 2])
    for channel, name in enumerate(("red", "green", "blue")):
        vertices[name] = colours[:, channel]
    vertices["probability"] = voxels.probability()[occupied]
    z_range = f"{centres[:, 2].min():.6g} {centres[:, 2].max():.6g}" if len(centres) else "none"
    properties = "".join(f"property {_PLY_TYPES[vertex[n].str]} {n}\n" for n in vertex.names)
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment occupied voxels written by vogjax\n"
        f"comment voxel_size {voxels.voxel_size!r}\ncomment colour viridis over z {z_range}\n"
        f"element vertex {len(vertices)}\n{properties}end_header\n"
    )
    with AtomicPath(Path(path)) as temporary, open(temporary, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertices.tobytes())
    return len(vertices)


_PLY_TYPES = {"<f4": "float", "<f8": "double", "|u1": "uchar"}
