"""Files: map files, run files, exports and imports.

The package exports the map file format itself (one file per map, versioned, checksummed,
published atomically); each other format has a module of its own:

- `vogjax.io.mapfile`: the .vog map file (`write_map_file`, `read_map_file`);
- `vogjax.io.voxels`: `VoxelSet`, what the exporters read of any map, and `load_map`, which
  opens a .vog file as the class its header names;
- `vogjax.io.dataset`: recorded runs, one HDF5 file per run (`DatasetWriter`, `Dataset`,
  `ScanBatch`);
- `vogjax.io.octomap`: OctoMap .bt and .ot files; `vogjax.io.ply`: PLY point clouds of the
  occupied voxels; `vogjax.io.tum`: trajectories in the TUM format (evo);
- `vogjax.io.rosbag`: ROS 1 and ROS 2 bags into run files, with `vogjax.io.pointcloud2` (a
  PointCloud2's fields by name), `vogjax.io.deskew` (per-point time layouts, motion
  compensation) and `vogjax.io.depth_image` (depth images through the pinhole model);
- `vogjax.io.atomic`: atomic publication of files and folders, which every writer uses.

Examples
--------
>>> import tempfile, pathlib
>>> path = pathlib.Path(tempfile.mkdtemp()) / "tiny.vog"
>>> write_map_file(path, "Example", {"note": "hi"}, {"values": [1.0, 2.0]})
>>> metadata, arrays = read_map_file(path, "Example")
>>> metadata["note"], arrays["values"].tolist()
('hi', [1.0, 2.0])
"""

from .mapfile import FORMAT_VERSION, read_map_file, write_map_file

__all__ = ["FORMAT_VERSION", "read_map_file", "write_map_file"]
