"""Files: map files (one file per map, versioned, checksummed)."""

from .mapfile import FORMAT_VERSION, read_map_file, write_map_file

__all__ = ["FORMAT_VERSION", "read_map_file", "write_map_file"]
