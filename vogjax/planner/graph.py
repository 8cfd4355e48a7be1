"""The explored graph: where the vehicle has been and where its trees could have taken it, for
a global step when the local tree finds little left to see (GBPlanner's global planning).

Every plan adds its tree: the root (the vehicle's state then), each node and each edge, which
was collision-free in the map of that moment. Consecutive roots are joined by the motion the
vehicle flew between them: that water is known to be passable, whatever the map says of it.
A global step (`best_target`) re-counts, on the current map, the gain of the tree edges that
lead to the vertices never flown to (the most promising ones the trees left behind), finds the
quickest way to each through the graph (Dijkstra over edge times), and picks the vertex with the
most gain per second of the whole trip; the caller checks the trip's edges against the current
map before flying them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from vogjax.config.planner import PlannerConfig
from vogjax.geometry import wrap_angle

# Vertices the graph keeps at most; beyond, the oldest unvisited ones with the least gain go.
MAX_VERTICES = 20_000


@dataclasses.dataclass(frozen=True)
class Trip:
    """A global step's plan: `vertices` (K,) graph indices from the vehicle's vertex (excluded) to
    the target; `states` (K,4) their x, y, z, yaw; `flown` (K,) whether each edge onto a vertex
    was flown before (else a tree edge, to be checked again); `gain_m3` the target edge's gain on
    the current map; `seconds` the trip's time under the vehicle's limits; `rate` their ratio."""

    vertices: np.ndarray
    states: np.ndarray
    flown: np.ndarray
    gain_m3: float
    seconds: float
    rate: float


class ExploredGraph:
    """Vertices (x, y, z, yaw), undirected edges with their flight times, per vertex the gain its
    tree edge promised when it was planned and whether the vehicle has stood there."""

    def __init__(self, config: PlannerConfig):
        self.config = config
        self.states = np.zeros((0, 4))
        self.promised = np.zeros(0)
        self.visited = np.zeros(0, bool)
        self.parent = np.zeros(0, np.int64)  # the vertex its tree edge starts from (-1: none)
        self.edges: list[tuple[int, int, bool]] = []  # (i, j, flown)
        self.last_visit = -1

    def __len__(self) -> int:
        return len(self.states)

    def _add_vertex(self, state: np.ndarray, promised: float, parent: int, visited: bool) -> int:
        self.states = np.vstack([self.states, state[None]])
        self.promised = np.r_[self.promised, promised]
        self.visited = np.r_[self.visited, visited]
        self.parent = np.r_[self.parent, parent]
        return len(self.states) - 1

    def visit(self, state: np.ndarray) -> int:
        """The vehicle stands at `state` (4,): a visited vertex, joined to the last one by the
        motion flown between them. Returns its index."""
        vertex = self._add_vertex(np.asarray(state, np.float64), 0.0, -1, True)
        if self.last_visit >= 0:
            self.edges.append((self.last_visit, vertex, True))
        self.last_visit = vertex
        return vertex

    def add_tree(self, root_vertex: int, states: np.ndarray, parents: np.ndarray, gains: np.ndarray) -> None:
        """A plan's tree: states (N+1,4) with the root first, parents (N+1,) (-1 for the root),
        gains (N+1,) each node's edge gain (m^3) when planned; the root is `root_vertex`."""
        index = np.full(len(states), -1, np.int64)
        index[0] = root_vertex
        for n in range(1, len(states)):  # parents come before their children
            index[n] = self._add_vertex(states[n], float(gains[n]), int(index[parents[n]]), False)
            self.edges.append((int(index[parents[n]]), int(index[n]), False))
        if len(self.states) > MAX_VERTICES:
            self._forget(len(self.states) - MAX_VERTICES)

    def _forget(self, count: int) -> None:
        """Drop `count` unvisited leaf-most vertices with the least promise (keeps indices of the
        rest consistent by rebuilding)."""
        candidates = np.flatnonzero(~self.visited)
        drop = set(candidates[np.argsort(self.promised[candidates], kind="stable")[:count]].tolist())
        keep = np.array([i for i in range(len(self.states)) if i not in drop])
        renumber = np.full(len(self.states), -1, np.int64)
        renumber[keep] = np.arange(len(keep))
        self.states, self.promised, self.visited = self.states[keep], self.promised[keep], self.visited[keep]
        self.parent = np.where(self.parent[keep] >= 0, renumber[np.maximum(self.parent[keep], 0)], -1)
        self.edges = [
            (int(renumber[i]), int(renumber[j]), f) for i, j, f in self.edges if i not in drop and j not in drop
        ]
        self.last_visit = int(renumber[self.last_visit]) if self.last_visit >= 0 else -1

    def times(self) -> coo_matrix:
        """The graph's edge times (seconds under the vehicle's limits), as a sparse matrix."""
        if not self.edges:
            return coo_matrix((len(self.states), len(self.states)))
        i, j = np.array([e[0] for e in self.edges]), np.array([e[1] for e in self.edges])
        a, b = self.states[i], self.states[j]
        seconds = self.config.edge_seconds(np.linalg.norm(b[:, :3] - a[:, :3], axis=1), wrap_angle(b[:, 3] - a[:, 3]))
        n = len(self.states)
        return coo_matrix((np.r_[seconds, seconds], (np.r_[i, j], np.r_[j, i])), shape=(n, n))

    def candidates(self, origin: np.ndarray, count: int, min_distance_m: float) -> np.ndarray:
        """Up to `count` unvisited vertices at least min_distance_m from `origin` (3,), most
        promising first (ties: the newest)."""
        far = np.linalg.norm(self.states[:, :3] - origin, axis=1) >= min_distance_m
        pool = np.flatnonzero(~self.visited & far & (self.promised > 0) & (self.parent >= 0))
        order = np.lexsort((-pool, -self.promised[pool]))
        return pool[order[:count]]

    def trips(self, start: int, targets: np.ndarray, gains: np.ndarray) -> list[Trip]:
        """Trips from vertex `start` to each target with its gain on the current map, best rate
        first (unreachable targets and those without gain left out)."""
        if not len(targets):
            return []
        seconds, previous = dijkstra(self.times().tocsr(), indices=start, return_predecessors=True)
        out = []
        for target, gain in zip(targets, gains):
            if gain <= 0 or not np.isfinite(seconds[target]):
                continue
            path = [int(target)]
            while path[-1] != start:
                path.append(int(previous[path[-1]]))
            path = path[::-1][1:]
            flown_edges = {(i, j) for i, j, f in self.edges if f} | {(j, i) for i, j, f in self.edges if f}
            hops = [start, *path]
            flown = np.array([(a, b) in flown_edges for a, b in zip(hops[:-1], hops[1:])])
            out.append(
                Trip(
                    np.array(path),
                    self.states[path],
                    flown,
                    float(gain),
                    float(seconds[target]),
                    float(gain / max(seconds[target], 1e-9)),
                )
            )
        out.sort(key=lambda trip: -trip.rate)
        return out
