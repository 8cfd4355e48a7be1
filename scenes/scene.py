"""Scene: a triangle mesh with the region a vehicle explores and where it starts, plus ground truth."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import trimesh
import warp as wp

FREE = 1
OCCUPIED = 2
INSIDE = 3  # inside a solid: never observable, left out of evaluations


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """Dense labels over a box of voxels: labels[i, j, k] is voxel first_key + (i, j, k);
    FREE (water), OCCUPIED (the surface passes through it) or INSIDE (within a solid)."""

    voxel_size: float
    first_key: np.ndarray  # (3,) int
    labels: np.ndarray  # (nx, ny, nz) int8

    def keys(self, label: int) -> np.ndarray:
        return np.argwhere(self.labels == label) + self.first_key

    def centres(self, label: int) -> np.ndarray:
        return (self.keys(label) + 0.5) * self.voxel_size


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """name; mesh (trimesh.Trimesh, z up, metres); bounds (2,3) the exploration box the vehicle
    stays in; start_pose (4,4) T_world_vehicle at the start."""

    name: str
    mesh: trimesh.Trimesh
    bounds: np.ndarray
    start_pose: np.ndarray

    @functools.cached_property
    def warp_mesh(self) -> wp.Mesh:
        return _warp_mesh(self.mesh)

    def region(self) -> np.ndarray:
        """(2,3) box holding the mesh and the exploration box."""
        return np.stack([np.minimum(self.mesh.bounds[0], self.bounds[0]),
                         np.maximum(self.mesh.bounds[1], self.bounds[1])])

    def occupancy(self, voxel_size: float) -> GroundTruth:
        region = self.region()
        first = np.floor(region[0] / voxel_size).astype(np.int64) - 1
        last = np.floor(region[1] / voxel_size).astype(np.int64) + 1
        shape = tuple(last - first + 1)
        labels = np.full(shape, FREE, np.int8)

        # inside solids: generalised winding number of each voxel centre
        grid = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).reshape(-1, 3)
        centres = (grid + first + 0.5) * voxel_size
        # Parts touch (boxes on a floor); a winding number per closed part stays exact there.
        for part in self.mesh.split(only_watertight=False):
            labels.reshape(-1)[_inside(_warp_mesh(part), centres)] = INSIDE
        # the surface: points on every triangle, a quarter voxel apart
        for points in triangle_points(self.mesh, voxel_size / 4):
            labels[tuple((np.floor(points / voxel_size).astype(np.int64) - first).T)] = OCCUPIED
        return GroundTruth(voxel_size, first, labels)

    def surface_points(self, count: int, seed: int = 0) -> np.ndarray:
        """(count,3) points spread evenly over the surface (for reconstruction RMSE)."""
        points, _ = trimesh.sample.sample_surface_even(self.mesh, count, seed=seed)
        return np.asarray(points)


def triangle_points(mesh: trimesh.Trimesh, spacing: float):
    """Chunks of points on a barycentric grid over each triangle, `spacing` or less apart."""
    triangles = mesh.triangles
    edges = np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2).max(axis=1)
    steps = np.maximum(np.ceil(edges / spacing).astype(int), 1)
    for n in np.unique(steps):
        group = triangles[steps == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        u, v = i[keep] / n, j[keep] / n
        a, b, c = group[:, 0, None], group[:, 1, None], group[:, 2, None]
        yield (a + (b - a) * u[None, :, None] + (c - a) * v[None, :, None]).reshape(-1, 3)


@wp.kernel
def _winding_inside(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), inside: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    # Built-in solids are at most a couple of metres thick: farther from a surface is water.
    query = wp.mesh_query_point_sign_winding_number(mesh, points[tid], 1.5, 2.0, 0.5)
    inside[tid] = wp.where(query.result and query.sign < 0.0, 1, 0)


def _warp_mesh(mesh: trimesh.Trimesh) -> wp.Mesh:
    from vogjax import _warp

    _warp.init()
    return wp.Mesh(points=wp.array(mesh.vertices, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(mesh.faces.reshape(-1), dtype=wp.int32, device="cpu"))


def _inside(mesh: wp.Mesh, points: np.ndarray) -> np.ndarray:
    out = wp.zeros(len(points), dtype=wp.int32, device="cpu")
    wp.launch(_winding_inside, dim=len(points), inputs=[mesh.id, wp.array(points, dtype=wp.vec3, device="cpu")],
              outputs=[out], device="cpu")
    return out.numpy().astype(bool)


def pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = [x, y, z]
    return T


def placed(mesh: trimesh.Trimesh, T: np.ndarray) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_transform(T)
    return mesh


def cylinder_between(a, b, radius: float, sections: int = 24) -> trimesh.Trimesh:
    """A closed cylinder from point a to point b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = b - a
    T = trimesh.geometry.align_vectors([0, 0, 1], axis / np.linalg.norm(axis))
    T[:3, 3] = (a + b) / 2
    return trimesh.creation.cylinder(radius=radius, height=np.linalg.norm(axis), sections=sections, transform=T)


def box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    T = np.eye(4)
    T[:3, 3] = (lo + hi) / 2
    return trimesh.creation.box(extents=hi - lo, transform=T)
