"""The vessel above the waterline as a few convex pieces: what hides the water in an image.

The vessel's own pixels are found by projecting 3-D point sets and filling their convex
hulls (a convex set projects to the convex hull of its projected corners, through any
pinhole camera). One hull over a whole vessel also holds the slanted skirt from a
deckhouse's roof to the deck's ends, and from a mast forward to a deckhouse aft, and seen
obliquely that skirt covers water the vessel does not hide: an obstacle there would be
erased as the vessel's own pixels. :func:`above_water_layers` therefore cuts the vessel into

1. **slab pieces**: horizontal slabs :data:`LAYER_SLAB_M` thick, each split into its
   connected pieces (faces sharing an edge in the slab). A face's part in a slab is the
   convex hull of its corners in the slab and its edges' crossings of the slab's planes,
   so the pieces' hulls contain the mesh;
2. **joined where it costs nothing**: two pieces (or layers) are joined while the hull of
   both holds at most :data:`LAYER_GROWTH` more volume than the pieces they are made of
   (the hull's slabs join, a deckhouse's join, a stay's join along it; a deckhouse and a
   mast at one height do not);
3. **joined where it costs least**, until at most :data:`MAX_LAYERS` remain: the pair
   whose joined hull adds the least volume to theirs (a rig's stays join the mast, not the
   deckhouse across the deck). Every frame projects each layer, so their number is its cost.

Pairs are only weighed between neighbours (step 2: pieces that touch, in the same or the
next slab; step 3: also the :data:`NEIGHBOURS` nearest layers), which keeps a mesh of 10^5
faces to seconds.
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np

#: the thickness of the thin slabs the layers are made of (m), and at most this many slabs
LAYER_SLAB_M = 0.25
MAX_LAYER_SLABS = 400
#: how much more volume (a share) a joined hull may hold than the slab pieces inside it
LAYER_GROWTH = 0.1
#: at most this many layers (each costs a projection and a fill per frame)
MAX_LAYERS = 12
#: pieces whose boxes are this close (m) touch: joining them may cost nothing
TOUCH_M = 0.01
#: step 3 weighs each layer against this many nearest (by centre); a joined layer keeps at
#: most MAX_NEIGHBOURS (the nearest by box) of its two parts' neighbours
NEIGHBOURS = 8
MAX_NEIGHBOURS = 24
#: volumes below this are nothing (m^3): a flat plate, a thin stay
_NO_VOLUME_M3 = 1e-6
_CHUNK = 100_000


def _hull(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The corners of a point set's convex hull and its volume (m^3). Qhull joggles the
    points ("QJ": by about 1e-11 of their extent) rather than merging coplanar facets,
    which is three times faster on box-like pieces; a flat set (a plate, the pieces of a
    stay) gets a volume of about nothing. Under four points are kept as they are."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 4:
        return points, 0.0
    try:
        hull = ConvexHull(points, qhull_options="QJ")
    except (QhullError, ValueError):
        return np.unique(points, axis=0), 0.0
    return points[hull.vertices], float(hull.volume)


def _corners(points: np.ndarray) -> np.ndarray:
    """A point set's convex hull's corners, coplanar facets merged (no joggled extras: each
    is projected every frame); a flat set keeps the joggled hull's."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return points


def _slab_range(levels: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """The first and last slab that a height range ``[low, high]`` touches (its ends on a
    level belong to both slabs there)."""
    last = len(levels) - 2
    first = np.clip(np.searchsorted(levels, low, "left") - 1, 0, last)
    final = np.clip(np.searchsorted(levels, high, "right") - 1, 0, last)
    return first, final


def _slab_pieces(vertices: np.ndarray, faces: np.ndarray, adjacency: np.ndarray,
                 adjacency_edges: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """Each slab's connected pieces as ``(slab, points)``: the points are the pieces' face
    corners in the slab and the crossings ``p + t (q - p)``, ``t = (l - h_p) / (h_q - h_p)``
    of their edges with the slab's planes ``l``.

    A node is one face in one slab; two nodes are joined when their faces share an edge
    that reaches into that slab; the pieces are the graph's connected components."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    heights = -vertices[:, 2]
    top = float(heights.max())
    n_slabs = max(1, min(MAX_LAYER_SLABS, math.ceil(top / LAYER_SLAB_M)))
    levels = np.linspace(0.0, top, n_slabs + 1)
    face_h = heights[faces]
    first, last = _slab_range(levels, face_h.min(axis=1), face_h.max(axis=1))
    counts = last - first + 1
    start = np.cumsum(counts) - counts                 # node of each face's first slab
    n_nodes = int(counts.sum())
    node_face = np.repeat(np.arange(len(faces)), counts)
    node_slab = first[node_face] + np.arange(n_nodes) - start[node_face]

    edge_h = heights[adjacency_edges]
    e_first, e_last = _slab_range(levels, edge_h.min(axis=1), edge_h.max(axis=1))
    e_counts = e_last - e_first + 1
    pair = np.repeat(np.arange(len(adjacency)), e_counts)
    slab = e_first[pair] + np.arange(int(e_counts.sum())) - np.repeat(
        np.cumsum(e_counts) - e_counts, e_counts)
    fa, fb = adjacency[pair, 0], adjacency[pair, 1]
    a, b = start[fa] + slab - first[fa], start[fb] + slab - first[fb]
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n_nodes, n_nodes))
    _, piece_of_node = connected_components(graph, directed=False)

    points, owners = [], []
    corners_all = vertices[faces]                                  # (F, 3, 3)
    for lo in range(0, n_nodes, _CHUNK):
        nodes = np.arange(lo, min(lo + _CHUNK, n_nodes))
        f, k = node_face[nodes], node_slab[nodes]
        below, above = levels[k], levels[k + 1]
        corners, h = corners_all[f], face_h[f]
        inside = (h >= below[:, None]) & (h <= above[:, None])
        points.append(corners[inside])
        owners.append(np.repeat(piece_of_node[nodes], inside.sum(axis=1)))
        for i, j in ((0, 1), (1, 2), (2, 0)):
            p, q, hp, hq = corners[:, i], corners[:, j], h[:, i], h[:, j]
            for level in (below, above):
                cross = (np.minimum(hp, hq) < level) & (np.maximum(hp, hq) > level)
                t = (level[cross] - hp[cross]) / (hq[cross] - hp[cross])
                points.append(p[cross] + t[:, None] * (q[cross] - p[cross]))
                owners.append(piece_of_node[nodes[cross]])
    points, owners = np.vstack(points), np.concatenate(owners)
    order = np.argsort(owners, kind="stable")
    points, owners = points[order], owners[order]
    piece_slab = np.zeros(int(piece_of_node.max()) + 1, int)
    piece_slab[piece_of_node] = node_slab
    cuts = np.flatnonzero(np.diff(owners)) + 1
    return [(int(piece_slab[group[0]]), pts)
            for group, pts in zip(np.split(owners, cuts), np.split(points, cuts), strict=True)]


class _Layers:
    """The pieces being joined: each a hull (corners, volume), the volume of the slab pieces
    inside it (``content``), its box, and its neighbours (ids of live layers weighed
    against it)."""

    def __init__(self, pieces: list[tuple[int, np.ndarray]]):
        self.corners, self.volume, self.content = [], [], []
        for _, points in pieces:
            corners, volume = _hull(points)
            self.corners.append(corners)
            self.volume.append(volume)
            self.content.append(volume)
        self.low = [c.min(axis=0) for c in self.corners]
        self.high = [c.max(axis=0) for c in self.corners]
        self.alive = [True] * len(pieces)
        self.neighbours: list[set[int]] = [set() for _ in pieces]
        slab = np.array([k for k, _ in pieces])
        low, high = np.array(self.low), np.array(self.high)
        for k in np.unique(slab):                  # touching, in the same or the next slab
            ids = np.flatnonzero(slab == k)
            others = np.flatnonzero((slab == k) | (slab == k + 1))
            gap = np.maximum(low[ids, None] - high[None, others],
                             low[None, others] - high[ids, None]).max(axis=2)
            for i, j in zip(*np.nonzero(gap <= TOUCH_M), strict=True):
                if ids[i] != others[j]:
                    self.neighbours[ids[i]].add(int(others[j]))
                    self.neighbours[others[j]].add(int(ids[i]))

    @property
    def count(self) -> int:
        return sum(self.alive)

    def gap(self, i: int, j: int) -> float:
        """The distance between two layers' boxes (m; 0 where they overlap)."""
        apart = np.maximum(self.low[i] - self.high[j], self.low[j] - self.high[i])
        return float(np.linalg.norm(np.maximum(apart, 0.0)))

    def meet_nearest(self) -> None:
        """Weigh each live layer against its :data:`NEIGHBOURS` nearest by centre (all of
        them when there are few)."""
        from scipy.spatial import cKDTree

        live = [i for i, alive in enumerate(self.alive) if alive]
        centres = [self.corners[i].mean(axis=0) for i in live]
        k = min(len(live), NEIGHBOURS + 1 if len(live) > 4 * NEIGHBOURS else len(live))
        _, near = cKDTree(centres).query(centres, k=k)
        for i, row in zip(live, np.asarray(near).reshape(len(live), -1), strict=True):
            for j in (live[n] for n in row):
                if j != i:
                    self.neighbours[i].add(j)
                    self.neighbours[j].add(i)

    def joined(self, i: int, j: int) -> tuple[np.ndarray, float]:
        return _hull(np.vstack((self.corners[i], self.corners[j])))

    def join(self, i: int, j: int, corners: np.ndarray, volume: float) -> int:
        """Join layers ``i`` and ``j`` into a new one; returns its id. It keeps the two's
        neighbours, the nearest :data:`MAX_NEIGHBOURS` where there are more (each is
        weighed after every join)."""
        k = len(self.corners)
        self.corners.append(corners)
        self.volume.append(volume)
        self.content.append(self.content[i] + self.content[j])
        self.low.append(np.minimum(self.low[i], self.low[j]))
        self.high.append(np.maximum(self.high[i], self.high[j]))
        self.alive[i] = self.alive[j] = False
        self.alive.append(True)
        near = [n for n in (self.neighbours[i] | self.neighbours[j]) - {i, j} if self.alive[n]]
        near.sort(key=lambda n: self.gap(n, k))
        for n in (*near[MAX_NEIGHBOURS:], i, j):
            self.neighbours[n].difference_update((i, j))
        self.neighbours.append(set(near[:MAX_NEIGHBOURS]))
        for n in self.neighbours[k]:
            self.neighbours[n].difference_update((i, j))
            self.neighbours[n].add(k)
        return k


def _join(layers: _Layers, cost, limit: float | None) -> None:
    """Join the cheapest pair of neighbours (by ``cost(i, j, corners, volume)``) while its
    cost is at most ``limit`` (``None``: while more than :data:`MAX_LAYERS` remain)."""
    heap: list = []
    order = itertools.count()               # ties go first come, first served

    def push(i: int, j: int) -> None:
        corners, volume = layers.joined(i, j)
        heapq.heappush(heap, (cost(i, j, volume), next(order), i, j, corners, volume))

    for i in range(len(layers.corners)):
        if layers.alive[i]:
            for j in layers.neighbours[i]:
                if j > i and layers.alive[j]:
                    push(i, j)
    while heap:
        if limit is None and layers.count <= MAX_LAYERS:
            return
        value, _, i, j, corners, volume = heapq.heappop(heap)
        if limit is not None and value > limit:
            return
        if not (layers.alive[i] and layers.alive[j]):
            continue
        k = layers.join(i, j, corners, volume)
        for n in layers.neighbours[k]:
            push(n, k)
    if limit is None and layers.count > MAX_LAYERS:    # apart (an antenna over a gap): all pairs
        live = [i for i, alive in enumerate(layers.alive) if alive]
        for i in live:
            layers.neighbours[i].update(j for j in live if j != i)
        _join(layers, cost, None)


def join_pieces(pieces: list[tuple[int, np.ndarray]]) -> tuple[np.ndarray, ...]:
    """Join slab pieces ``(slab, points)`` into layers (steps 2 and 3 of the module's
    docstring); each returned as its convex hull's corners, lowest first."""
    layers = _Layers(pieces)

    def excess(i: int, j: int, volume: float) -> float:
        """The joined hull's volume over the pieces' (1 when it holds nothing more)."""
        content = layers.content[i] + layers.content[j]
        return (volume + _NO_VOLUME_M3) / (content + _NO_VOLUME_M3)

    def added(i: int, j: int, volume: float) -> float:
        """The volume the joined hull holds beyond the two layers' own hulls (m^3)."""
        return volume - layers.volume[i] - layers.volume[j]

    _join(layers, excess, 1.0 + LAYER_GROWTH)
    if layers.count > MAX_LAYERS:
        layers.meet_nearest()
        _join(layers, added, None)
    live = [i for i, alive in enumerate(layers.alive) if alive]
    live.sort(key=lambda i: (-float(layers.high[i][2]), -float(layers.low[i][2])))  # z down
    return tuple(_corners(layers.corners[i]) for i in live)


def above_water_layers(mesh_v) -> tuple[np.ndarray, ...]:
    """The part of a V-frame mesh above the waterline (``z`` down) as at most
    :data:`MAX_LAYERS` point sets whose convex hulls together contain it, each close to the
    vessel's own shape (see the module's docstring)."""
    above = mesh_v.slice_plane(plane_origin=[0.0, 0.0, 0.0], plane_normal=[0.0, 0.0, -1.0])
    if above is None or len(above.vertices) < 4:
        raise ValueError("no part of the hull mesh is above the waterline")
    above = above.copy()
    above.merge_vertices()                  # parts that share corners share edges
    pieces = _slab_pieces(np.asarray(above.vertices, float), np.asarray(above.faces),
                          np.asarray(above.face_adjacency), np.asarray(above.face_adjacency_edges))
    return join_pieces(pieces)
