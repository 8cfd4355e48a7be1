"""The occupancy maps, all on hashed 8x8x8 voxel blocks (`blocks`) read through `BlockMap`:

- `VoxelMap`: OctoMap's update rule, batched integration, queries, files;
- `Submap` and `VogMap`: submaps hung off pose-graph nodes, queried as their sum (virtual map);
- `GlobalMap`: the one map planners query, kept equal to a full merge by undo/redo;
- `ConfidenceMap`: a distribution over the occupancy level per voxel (Agha-mohammadi).

Queries answer UNKNOWN (0), FREE (1) or OCCUPIED (2) per voxel; ray casts return a
`RaycastResult` (`ConfidenceRaycast` for the confidence-rich map), `GlobalMap.update_poses` an
`UpdateReport`. Points are (M, 3) arrays, metres, in the map's frame (the world's; a Submap's
own); voxel k covers ``[k*s, (k+1)*s)`` on each axis; bad input raises ValueError naming the
argument before anything changes.
"""

from vogjax.maps.blockmap import FREE, OCCUPIED, UNKNOWN, BlockMap, RaycastResult
from vogjax.maps.confidence import ConfidenceMap, ConfidenceRaycast
from vogjax.maps.globalmap import GlobalMap, UpdateReport
from vogjax.maps.submaps import Submap, VogMap
from vogjax.maps.voxelmap import VoxelMap

__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "BlockMap",
    "ConfidenceMap",
    "ConfidenceRaycast",
    "GlobalMap",
    "RaycastResult",
    "Submap",
    "UpdateReport",
    "VogMap",
    "VoxelMap",
]
