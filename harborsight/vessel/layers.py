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
   mast at one height do not). A connected part of the mesh that is convex (a post, a box)
   is taken whole at once;
3. **joined where it hides least**, until at most :data:`MAX_LAYERS` remain: the pair
   whose joined hull adds the least surface to theirs (a convex body's mean projected area
   over all views is a quarter of its surface, so this is the water the join hides on
   average). Added volume was the first measure: two thin posts joined into a fence have
   none, and seen obliquely 16 poles joined so hid water out to 21 m from the hull. Every
   frame projects each layer, so their number is its cost.

Pairs are only weighed between neighbours (step 2: pieces that touch, in the same or the
next slab; step 3: also the :data:`NEIGHBOURS` nearest layers, more where groups lie
apart), which keeps a mesh of 10^5 faces to seconds.
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
MAX_LAYERS = 48
#: the pose alignment fits at most this many, those of the largest surface (:func:`largest`)
MAX_ALIGNMENT_LAYERS = 8
#: pieces whose boxes are this close (m) touch: joining them may cost nothing
TOUCH_M = 0.01
#: step 3 weighs each layer against this many nearest (by centre); a joined layer keeps at
#: most MAX_NEIGHBOURS (the nearest by box) of its two parts' neighbours
NEIGHBOURS = 8
MAX_NEIGHBOURS = 12
#: corners this close (m) are one: an exporter that tessellates each patch on its own
#: writes their shared corners a hair apart, and the faces would share no edge
MERGE_TOLERANCE_M = 1e-4
#: volumes below this are nothing (m^3): a flat plate, a thin stay
_NO_VOLUME_M3 = 1e-6
_CHUNK = 100_000


def _hull(points: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The corners of a point set's convex hull, its volume (m^3) and its surface area
    (m^2). Qhull joggles the points ("QJ": by about 1e-11 of their extent) rather than
    merging coplanar facets, which is three times faster on box-like pieces; a flat set (a
    plate, the pieces of a stay) gets a volume of about nothing and twice its area. Under
    four points are kept as they are (no volume, no area)."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 4:
        return points, 0.0, 0.0
    try:
        hull = ConvexHull(points, qhull_options="QJ")
    except (QhullError, ValueError):
        return np.unique(points, axis=0), 0.0, 0.0
    return points[hull.vertices], float(hull.volume), float(hull.area)


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
                 adjacency_edges: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """Each slab's connected pieces as ``(slab, part, points)``: ``part`` is the connected
    part of the mesh the piece belongs to; the points are the piece's face corners in the
    slab and the crossings ``p + t (q - p)``, ``t = (l - h_p) / (h_q - h_p)`` of their
    edges with the slab's planes ``l``.

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
    faces_graph = coo_matrix((np.ones(len(adjacency), np.int8), (adjacency[:, 0], adjacency[:, 1])),
                             shape=(len(faces), len(faces)))
    _, part_of_face = connected_components(faces_graph, directed=False)

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
    piece_part = np.zeros_like(piece_slab)
    piece_part[piece_of_node] = part_of_face[node_face]
    cuts = np.flatnonzero(np.diff(owners)) + 1
    return [(int(piece_slab[group[0]]), int(piece_part[group[0]]), pts)
            for group, pts in zip(np.split(owners, cuts), np.split(points, cuts), strict=True)]


class _Layers:
    """The pieces being joined: each a hull (corners, volume, area), the volume of the slab
    pieces inside it (``content``), its box, and its neighbours (ids of live layers weighed
    against it)."""

    def __init__(self, pieces: list[tuple[int, int, np.ndarray]]):
        self.corners, self.volume, self.area, self.content = [], [], [], []
        self.low, self.high, self.alive, self.neighbours = [], [], [], []
        self.count = 0
        slabs: list[int] = []
        by_part: dict[int, list[int]] = {}
        for slab, part, points in pieces:
            self._add(*_hull(points))
            slabs.append(slab)
            by_part.setdefault(part, []).append(len(slabs) - 1)
        slab = np.array(slabs)
        low, high = np.array(self.low), np.array(self.high)
        for k in np.unique(slab):                  # touching, in the same or the next slab
            ids = np.flatnonzero(slab == k)
            others = np.flatnonzero((slab == k) | (slab == k + 1))
            for rows in np.array_split(ids, max(1, len(ids) * len(others) // 1_000_000 + 1)):
                gap = np.maximum(low[rows, None] - high[None, others],
                                 low[None, others] - high[rows, None]).max(axis=2)
                for i, j in zip(*np.nonzero(gap <= TOUCH_M), strict=True):
                    if rows[i] != others[j]:
                        self.neighbours[rows[i]].add(int(others[j]))
                        self.neighbours[others[j]].add(int(rows[i]))
        for ids in by_part.values():   # a convex part (a post, a box) whole, at one hull's cost
            if len(ids) > 1:
                corners, volume, area = _hull(np.vstack([self.corners[i] for i in ids]))
                if self.fits(volume, sum(self.content[i] for i in ids)):
                    self.merge(ids, corners, volume, area)

    def _add(self, corners: np.ndarray, volume: float, area: float,
             content: float | None = None) -> int:
        self.corners.append(corners)
        self.volume.append(volume)
        self.area.append(area)
        self.content.append(volume if content is None else content)
        self.low.append(corners.min(axis=0))
        self.high.append(corners.max(axis=0))
        self.alive.append(True)
        self.neighbours.append(set())
        self.count += 1
        return len(self.corners) - 1

    @staticmethod
    def fits(volume: float, content: float) -> bool:
        """Whether a hull of ``volume`` over pieces of ``content`` holds nothing more
        (within :data:`LAYER_GROWTH`)."""
        return volume + _NO_VOLUME_M3 <= (1.0 + LAYER_GROWTH) * (content + _NO_VOLUME_M3)

    def gap(self, i: int, j: int) -> float:
        """The distance between two layers' boxes (m; 0 where they overlap)."""
        apart = np.maximum(self.low[i] - self.high[j], self.low[j] - self.high[i])
        return float(np.linalg.norm(np.maximum(apart, 0.0)))

    def live(self) -> list[int]:
        return [i for i, alive in enumerate(self.alive) if alive]

    def meet_nearest(self, k: int) -> None:
        """Weigh each live layer against its ``k`` nearest by centre."""
        from scipy.spatial import cKDTree

        live = self.live()
        if len(live) < 2:
            return
        centres = [self.corners[i].mean(axis=0) for i in live]
        _, near = cKDTree(centres).query(centres, k=min(k + 1, len(live)))
        for i, row in zip(live, np.asarray(near).reshape(len(live), -1), strict=True):
            for j in (live[n] for n in row):
                if j != i:
                    self.neighbours[i].add(j)
                    self.neighbours[j].add(i)

    def joined(self, i: int, j: int) -> tuple[np.ndarray, float, float]:
        return _hull(np.vstack((self.corners[i], self.corners[j])))

    def merge(self, ids: list[int], corners: np.ndarray, volume: float, area: float) -> int:
        """Join layers ``ids`` into a new one; returns its id. It keeps their neighbours,
        the nearest :data:`MAX_NEIGHBOURS` (by box) where there are more (each is weighed
        after every join)."""
        k = self._add(corners, volume, area, sum(self.content[i] for i in ids))
        for i in ids:
            self.alive[i] = False
        self.count -= len(ids)
        gone = set(ids)
        near = [n for n in set().union(*(self.neighbours[i] for i in ids)) - gone if self.alive[n]]
        near.sort(key=lambda n: self.gap(n, k))
        for n in (*near[MAX_NEIGHBOURS:], *ids):
            self.neighbours[n].difference_update(gone)
        self.neighbours[k] = set(near[:MAX_NEIGHBOURS])
        for n in self.neighbours[k]:
            self.neighbours[n].difference_update(gone)
            self.neighbours[n].add(k)
        return k


def _join(layers: _Layers, cost, limit: float | None) -> None:
    """Join the cheapest pair of neighbours (by ``cost(i, j, volume, area)``) while its cost
    is at most ``limit`` (``None``: while more than :data:`MAX_LAYERS` remain)."""
    heap: list = []
    order = itertools.count()               # ties go first come, first served

    def push(i: int, j: int) -> None:
        corners, volume, area = layers.joined(i, j)
        heapq.heappush(heap, (cost(i, j, volume, area), next(order), i, j, corners, volume, area))

    for i in layers.live():
        for j in layers.neighbours[i]:
            if j > i and layers.alive[j]:
                push(i, j)
    k = NEIGHBOURS
    while True:
        while heap:
            if limit is None and layers.count <= MAX_LAYERS:
                return
            value, _, i, j, corners, volume, area = heapq.heappop(heap)
            if limit is not None and value > limit:
                return
            if not (layers.alive[i] and layers.alive[j]):
                continue
            new = layers.merge([i, j], corners, volume, area)
            for n in layers.neighbours[new]:
                push(n, new)
        if limit is not None or layers.count <= MAX_LAYERS or layers.count < 2:
            return
        k *= 2                  # groups apart (an antenna over a gap): more neighbours each
        before = {i: set(layers.neighbours[i]) for i in layers.live()}
        layers.meet_nearest(k)
        for i, near in before.items():
            for j in layers.neighbours[i] - near:
                if j > i:
                    push(i, j)


def join_pieces(pieces: list[tuple[int, int, np.ndarray]]) -> tuple[np.ndarray, ...]:
    """Join slab pieces ``(slab, part, points)`` into layers (steps 2 and 3 of the module's
    docstring); each returned as its convex hull's corners, lowest first."""
    layers = _Layers(pieces)

    def excess(i: int, j: int, volume: float, area: float) -> float:
        """The joined hull's volume over the pieces' (1 when it holds nothing more)."""
        content = layers.content[i] + layers.content[j]
        return (volume + _NO_VOLUME_M3) / (content + _NO_VOLUME_M3)

    def added(i: int, j: int, volume: float, area: float) -> float:
        """The surface the joined hull has beyond the two layers' own hulls (m^2): a
        convex body's mean projected area is a quarter of its surface (Cauchy), so this is
        what the join hides of the water, on average over the views."""
        return area - layers.area[i] - layers.area[j]

    _join(layers, excess, 1.0 + LAYER_GROWTH)
    if layers.count > MAX_LAYERS:
        layers.meet_nearest(NEIGHBOURS)
        _join(layers, added, None)
    live = layers.live()
    live.sort(key=lambda i: (-float(layers.high[i][2]), -float(layers.low[i][2])))  # z down
    return tuple(_corners(layers.corners[i]) for i in live)


def largest(layers: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """The :data:`MAX_ALIGNMENT_LAYERS` layers of the largest hull surface, in their order
    (all of them when there are no more)."""
    if len(layers) <= MAX_ALIGNMENT_LAYERS:
        return layers
    area = [_hull(np.asarray(layer, float))[2] for layer in layers]
    keep = sorted(np.argsort(area)[::-1][:MAX_ALIGNMENT_LAYERS])
    return tuple(layers[k] for k in keep)


def _corners_shared(vertices: np.ndarray, faces: np.ndarray):
    """The mesh with corners within :data:`MERGE_TOLERANCE_M` of each other made one (each
    cluster of them becomes its first corner), and the faces that collapse dropped."""
    import trimesh
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(vertices).query_pairs(MERGE_TOLERANCE_M, output_type="ndarray")
    n = len(vertices)
    _, cluster = connected_components(
        coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
        directed=False)
    first = np.full(cluster.max() + 1, n)
    np.minimum.at(first, cluster, np.arange(n))
    faces = cluster[faces]
    whole = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return trimesh.Trimesh(vertices[first], faces[whole], process=False)


def above_water_layers(mesh_v) -> tuple[np.ndarray, ...]:
    """The part of a V-frame mesh above the waterline (``z`` down) as at most
    :data:`MAX_LAYERS` point sets whose convex hulls together contain it, each close to the
    vessel's own shape (see the module's docstring)."""
    above = mesh_v.slice_plane(plane_origin=[0.0, 0.0, 0.0], plane_normal=[0.0, 0.0, -1.0])
    if above is None or len(above.vertices) < 4:
        raise ValueError("no part of the hull mesh is above the waterline")
    above = _corners_shared(np.asarray(above.vertices, float), np.asarray(above.faces))
    pieces = _slab_pieces(np.asarray(above.vertices, float), np.asarray(above.faces),
                          np.asarray(above.face_adjacency), np.asarray(above.face_adjacency_edges))
    return join_pieces(pieces)
