"""Scene: a triangle mesh with the region a vehicle explores and where it starts, plus ground truth."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
import trimesh
import warp as wp

from vogjax.config.schema import Rule
from vogjax.kernels import ground_truth

FREE = 1
OCCUPIED = 2
INSIDE = 3  # inside a solid: never observable, left out of evaluations

# Ground truth voxels: evaluating a map against them holds their keys and centres (~100 bytes
# a voxel, 3.4 GB at the limit). Every built-in scene stays under it down to 0.05 m voxels, the
# 40 x 40 m warehouse down to 0.1 m.
MAX_GROUND_TRUTH_CELLS = 1 << 25
# Voxel centres tested for insideness per Warp launch (their keys and centres: ~100 MB).
_INSIDE_CHUNK = 1 << 21
MAX_LAPS = 1000
MAX_SURFACE_POINTS = 10_000_000


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """Dense ground-truth labels over a box of voxels.

    ``labels[i, j, k]`` is the label of voxel ``first_key + (i, j, k)``: FREE (water), OCCUPIED
    (the surface passes through it) or INSIDE (within a solid).

    Attributes
    ----------
    voxel_size : float
        Edge of a voxel, metres.
    first_key : (3,) ndarray of int64
        Integer index of the box's first voxel (voxel k covers ``[k*s, (k+1)*s)``).
    labels : (nx, ny, nz) ndarray of int8
        FREE (1), OCCUPIED (2) or INSIDE (3) per voxel.
    """

    voxel_size: float
    first_key: npt.NDArray[np.int64]
    labels: npt.NDArray[np.int8]

    def keys(self, label: int) -> npt.NDArray[np.int64]:
        """Integer indices of the voxels with one label.

        Parameters
        ----------
        label : int
            FREE, OCCUPIED or INSIDE.

        Returns
        -------
        (K, 3) ndarray of int64
            Their voxel keys, in C order of the box.
        """
        return np.argwhere(self.labels == label) + self.first_key

    def centres(self, label: int) -> npt.NDArray[np.float64]:
        """Centres of the voxels with one label.

        Parameters
        ----------
        label : int
            FREE, OCCUPIED or INSIDE.

        Returns
        -------
        (K, 3) ndarray of float64
            Their centres, metres, in the order of `keys`.
        """
        return (self.keys(label) + 0.5) * self.voxel_size


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A triangle mesh with the region a vehicle explores and where it starts, plus ground truth.

    Attributes
    ----------
    name : str
        The scene's name ("propeller", ...).
    mesh : trimesh.Trimesh
        The surfaces, z up, metres.
    bounds : (2, 3) ndarray of float
        The exploration box the vehicle stays in: min and max corner, metres.
    start_pose : (4, 4) ndarray of float
        ``T_world_vehicle`` at the start.
    default_survey : (W, 4) ndarray of float
        Waypoints (x, y, z in metres, yaw in radians) of the scene's survey, flown once.
    """

    name: str
    mesh: trimesh.Trimesh
    bounds: npt.NDArray[np.float64]
    start_pose: npt.NDArray[np.float64]
    default_survey: npt.NDArray[np.float64]

    def survey(self, laps: int = 2) -> npt.NDArray[np.float64]:
        """The default survey flown several times.

        Parameters
        ----------
        laps : int, optional
            Times to fly it, 1 to MAX_LAPS (1000).

        Returns
        -------
        (W * laps, 4) ndarray of float
            Waypoints (x, y, z, yaw).

        Raises
        ------
        ValueError
            If `laps` is not an integer in [1, MAX_LAPS].
        """
        Rule("integer", 1, MAX_LAPS).check("laps", laps)
        return np.concatenate([self.default_survey] * laps)

    @functools.cached_property
    def warp_mesh(self) -> wp.Mesh:
        """The mesh as a Warp mesh on the CPU, for ray casts (built once)."""
        return _warp_mesh(self.mesh)

    def region(self) -> npt.NDArray[np.float64]:
        """The box holding the mesh and the exploration box.

        Returns
        -------
        (2, 3) ndarray of float64
            Min and max corner, metres.
        """
        return np.stack(
            [np.minimum(self.mesh.bounds[0], self.bounds[0]), np.maximum(self.mesh.bounds[1], self.bounds[1])]
        )

    def occupancy(self, voxel_size: float) -> GroundTruth:
        """The ground truth: labels of the voxels over the region and one voxel around it.

        A voxel is INSIDE where its centre lies within a closed part (generalised winding
        number), OCCUPIED where the surface passes through it, FREE elsewhere.

        Parameters
        ----------
        voxel_size : float
            Edge of a voxel, metres.

        Returns
        -------
        GroundTruth
            The labels.

        Raises
        ------
        ValueError
            As `check_occupancy`: `voxel_size` not positive and finite, or more than
            MAX_GROUND_TRUTH_CELLS (2^25) voxels.
        """
        self.check_occupancy(voxel_size)
        region = self.region()
        first = np.floor(region[0] / voxel_size).astype(np.int64) - 1
        last = np.floor(region[1] / voxel_size).astype(np.int64) + 1
        shape = tuple(last - first + 1)
        labels = np.full(shape, FREE, np.int8)

        # inside solids: generalised winding number of each voxel centre, over the voxels
        # around each part (nothing beyond a closed part's box is inside it), slab by slab
        # Parts touch (boxes on a floor); a winding number per closed part stays exact there.
        for part in self.mesh.split(only_watertight=False):
            lo = np.clip(np.floor(part.bounds[0] / voxel_size).astype(np.int64) - 1 - first, 0, shape)
            hi = np.clip(np.floor(part.bounds[1] / voxel_size).astype(np.int64) + 2 - first, 0, shape)
            box = labels[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
            if not box.size:
                continue
            mesh = _warp_mesh(part)
            step = max(1, _INSIDE_CHUNK // (box.shape[1] * box.shape[2]))
            for i in range(0, box.shape[0], step):
                slab = box[i : i + step]
                grid = np.stack(np.meshgrid(*[np.arange(n) for n in slab.shape], indexing="ij"), -1).reshape(-1, 3)
                centres = (grid + (first + lo + [i, 0, 0]) + 0.5) * voxel_size
                slab[_inside(mesh, centres).reshape(slab.shape)] = INSIDE
        # the surface: points on every triangle, a quarter voxel apart
        for points in triangle_points(self.mesh, voxel_size / 4):
            labels[tuple((np.floor(points / voxel_size).astype(np.int64) - first).T)] = OCCUPIED
        return GroundTruth(voxel_size, first, labels)

    def check_occupancy(self, voxel_size: float) -> None:
        """Check that `occupancy(voxel_size)` can be built, before any long work.

        Parameters
        ----------
        voxel_size : float
            Edge of a voxel, metres.

        Raises
        ------
        ValueError
            If `voxel_size` is not positive and finite, or the region holds more than
            MAX_GROUND_TRUTH_CELLS (2^25) voxels of it (the error says how many).
        """
        Rule("number", 0, low_open=True).check("voxel_size", voxel_size)
        region = self.region()
        with np.errstate(over="ignore", invalid="ignore"):  # tiny voxels: inf or NaN, refused below
            cells = float(np.prod(np.floor(region[1] / voxel_size) - np.floor(region[0] / voxel_size) + 3))
        if not cells <= MAX_GROUND_TRUTH_CELLS:
            raise ValueError(
                f"voxel_size {voxel_size:g} m gives {cells:.3g} ground-truth voxels over scene "
                f"{self.name!r}, more than the limit of {MAX_GROUND_TRUTH_CELLS} "
                f"(use a larger voxel_size)"
            )

    def surface_points(self, count: int, seed: int = 0) -> npt.NDArray[np.float64]:
        """Points spread evenly over the surface, for the reconstruction RMSE.

        Parameters
        ----------
        count : int
            How many, 1 to MAX_SURFACE_POINTS (10^7).
        seed : int, optional
            Seed of the sampling: the same seed, the same points.

        Returns
        -------
        (count, 3) ndarray of float64
            Points on the mesh, metres (trimesh's even sampling may return fewer than `count`).

        Raises
        ------
        ValueError
            If `count` is not an integer in [1, MAX_SURFACE_POINTS].
        """
        Rule("integer", 1, MAX_SURFACE_POINTS).check("count", count)
        points, _ = trimesh.sample.sample_surface_even(self.mesh, count, seed=seed)
        return np.asarray(points)


def triangle_points(mesh: trimesh.Trimesh, spacing: float) -> Iterator[npt.NDArray[np.float64]]:
    """Points on a barycentric grid over each triangle, at most `spacing` apart along the edges.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The mesh.
    spacing : float
        Largest step between grid points along a triangle's longest edge, metres.

    Yields
    ------
    (P, 3) ndarray of float64
        The points of the triangles that share one grid size.
    """
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


def _warp_mesh(mesh: trimesh.Trimesh) -> wp.Mesh:
    from vogjax import devices

    devices.init()
    return wp.Mesh(
        points=wp.array(mesh.vertices, dtype=wp.vec3, device="cpu"),
        indices=wp.array(mesh.faces.reshape(-1), dtype=wp.int32, device="cpu"),
    )


def _inside(mesh: wp.Mesh, points: np.ndarray) -> np.ndarray:
    out = wp.zeros(len(points), dtype=wp.int32, device="cpu")
    wp.launch(
        ground_truth.flag_points_inside,
        dim=len(points),
        inputs=[mesh.id, wp.array(points, dtype=wp.vec3, device="cpu")],
        outputs=[out],
        device="cpu",
    )
    return out.numpy().astype(bool)


def placed(mesh: trimesh.Trimesh, T: npt.ArrayLike) -> trimesh.Trimesh:
    """A transformed copy of a mesh.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The mesh (left unchanged).
    T : (4, 4) array_like of float
        The transform applied to its vertices.

    Returns
    -------
    trimesh.Trimesh
        The moved copy.
    """
    mesh = mesh.copy()
    mesh.apply_transform(T)
    return mesh


def cylinder_between(a: npt.ArrayLike, b: npt.ArrayLike, radius: float, sections: int = 24) -> trimesh.Trimesh:
    """A closed cylinder from one point to another.

    Parameters
    ----------
    a, b : (3,) array_like of float
        Centres of its two ends, metres (distinct).
    radius : float
        Its radius, metres.
    sections : int, optional
        Facets around its circumference.

    Returns
    -------
    trimesh.Trimesh
        The watertight cylinder.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = b - a
    T = trimesh.geometry.align_vectors([0, 0, 1], axis / np.linalg.norm(axis))
    T[:3, 3] = (a + b) / 2
    return trimesh.creation.cylinder(radius=radius, height=np.linalg.norm(axis), sections=sections, transform=T)


def box(lo: npt.ArrayLike, hi: npt.ArrayLike) -> trimesh.Trimesh:
    """An axis-aligned box between two corners.

    Parameters
    ----------
    lo, hi : (3,) array_like of float
        Its min and max corner, metres.

    Returns
    -------
    trimesh.Trimesh
        The watertight box.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    T = np.eye(4)
    T[:3, 3] = (lo + hi) / 2
    return trimesh.creation.box(extents=hi - lo, transform=T)
