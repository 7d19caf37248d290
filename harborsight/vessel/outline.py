"""Hull outlines in the vessel frame V (x bow, y starboard, z down; origin at the GPS
antenna's horizontal position, at the waterline).

An outline is the convex hull of the hull cut (or projected) at a height, walked
clockwise seen from above and starting at the bow; see :mod:`harborsight.vessel.sections`.
"""

from __future__ import annotations

import numpy as np
import shapely
import trimesh
from shapely.geometry import MultiPoint, Polygon
from shapely.geometry.polygon import orient

#: Unit vector in V of each direction a mesh axis may point to.
AXIS_VECTORS: dict[str, tuple[float, float, float]] = {
    "bow": (1.0, 0.0, 0.0),
    "stern": (-1.0, 0.0, 0.0),
    "starboard": (0.0, 1.0, 0.0),
    "port": (0.0, -1.0, 0.0),
    "down": (0.0, 0.0, 1.0),
    "up": (0.0, 0.0, -1.0),
}


def mesh_axes_matrix(mesh_axes: list[str]) -> np.ndarray:
    """``A`` with ``p_V = A · p_mesh``: column i is where the mesh's axis i points in V."""
    if len(mesh_axes) != 3 or any(a not in AXIS_VECTORS for a in mesh_axes):
        raise ValueError(f"expected three of {sorted(AXIS_VECTORS)}, got {mesh_axes!r}")
    A = np.column_stack([AXIS_VECTORS[a] for a in mesh_axes])
    if abs(abs(np.linalg.det(A)) - 1.0) > 1e-9:
        raise ValueError(f"axes {mesh_axes!r} do not span 3-D (two name the same line)")
    return A


def mesh_in_vessel_frame(
    mesh: trimesh.Trimesh, mesh_axes: list[str], antenna_mesh: np.ndarray, waterline_mesh: float
) -> trimesh.Trimesh:
    """Move a mesh into V: ``p_V = A · (p_mesh - o)`` with ``o`` the antenna position whose
    vertical component is replaced by the waterline height (in mesh coordinates)."""
    A = mesh_axes_matrix(mesh_axes)
    vertical = int(np.flatnonzero(np.abs(A[2]) > 0.5)[0])
    offset = np.asarray(antenna_mesh, float).copy()
    offset[vertical] = waterline_mesh
    vertices = (np.asarray(mesh.vertices) - offset) @ A.T
    faces = np.asarray(mesh.faces)
    if np.linalg.det(A) < 0:  # mirrored axes: keep the faces' winding outward
        faces = faces[:, ::-1]
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


#: Outline vertices closer than this to the simplified outline are dropped (metres).
SIMPLIFY_TOLERANCE_M = 0.01


def convex_outline(points_xy: np.ndarray) -> np.ndarray:
    """Convex hull of V-frame x-y points, clockwise from above, starting at the bow.

    The bow is where the outline crosses the middle of its y-extent on the forward side
    (inserted as a vertex if it falls mid-edge), so blunt bows start on the centreline.
    """
    hull = MultiPoint(np.asarray(points_xy, float)).convex_hull
    if not isinstance(hull, Polygon) or hull.area <= 0:
        raise ValueError("the outline points do not enclose an area")
    # drop vertices that move the outline by less than SIMPLIFY_TOLERANCE_M (a subset of a
    # convex polygon's vertices is still convex); fewer edges make every frame cheaper
    hull = hull.simplify(SIMPLIFY_TOLERANCE_M, preserve_topology=True)
    ring = np.asarray(orient(hull, sign=1.0).exterior.coords)[:-1]
    y_mid = 0.5 * (ring[:, 1].min() + ring[:, 1].max())
    x_front = ring[:, 0].max() + 1.0
    cut = shapely.intersection(hull.exterior, shapely.LineString([(ring[:, 0].mean(), y_mid),
                                                                   (x_front, y_mid)]))
    bow = np.asarray(shapely.get_coordinates(cut))
    bow = bow[np.argmax(bow[:, 0])]
    gaps = np.hypot(*(ring - bow).T)
    if gaps.min() < 1e-9 * max(1.0, float(np.ptp(ring[:, 0]))):
        start = int(np.argmin(gaps))
        return np.roll(ring, -start, axis=0)
    nxt = np.roll(ring, -1, axis=0)
    seg = nxt - ring
    t = np.einsum("ij,ij->i", bow - ring, seg) / np.einsum("ij,ij->i", seg, seg)
    foot = ring + np.clip(t, 0, 1)[:, None] * seg
    edge = int(np.argmin(np.hypot(*(foot - bow).T)))
    ring = np.insert(ring, edge + 1, bow, axis=0)
    return np.roll(ring, -(edge + 1), axis=0)


def outline_from_mesh(mesh_v: trimesh.Trimesh, mode: str | float) -> np.ndarray:
    """Outline of a V-frame mesh: ``"waterline"`` (cut at z = 0), ``"silhouette"`` (all
    vertices projected onto the water plane) or a height in metres above the waterline."""
    if mode == "silhouette":
        return convex_outline(np.asarray(mesh_v.vertices)[:, :2])
    height = 0.0 if mode == "waterline" else float(mode)
    segments = trimesh.intersections.mesh_plane(
        mesh_v, plane_normal=[0.0, 0.0, 1.0], plane_origin=[0.0, 0.0, -height]
    )
    if len(segments) == 0:
        z = np.asarray(mesh_v.vertices)[:, 2]
        raise ValueError(
            f"the mesh does not reach {height:g} m above the waterline "
            f"(it spans {-z.max():.2f} to {-z.min():.2f} m)"
        )
    return convex_outline(np.asarray(segments).reshape(-1, 3)[:, :2])


BOW_SHAPES = ("pointed", "box")


def outline_from_dimensions(
    to_bow: float, to_stern: float, to_port: float, to_starboard: float, bow: str = "pointed"
) -> np.ndarray:
    """AIS-style box with a pointed bow (or a square one: ``bow="box"``, a barge or pontoon),
    in V (x bow, y starboard).

    The pointed bow is a triangle whose tip lies on the hull's centreline; its length is one
    beam, at most 35 % of the overall length.
    """
    if bow not in BOW_SHAPES:
        raise ValueError(f"bow {bow!r}: expected one of {', '.join(BOW_SHAPES)}")
    if bow == "box":
        return convex_outline(np.array([(to_bow, -to_port), (-to_stern, -to_port),
                                        (-to_stern, to_starboard), (to_bow, to_starboard)]))
    length = to_bow + to_stern
    beam = to_port + to_starboard
    bow_length = min(beam, 0.35 * length)
    y_tip = 0.5 * (to_starboard - to_port)
    shoulder_x = to_bow - bow_length
    points = np.array([
        (to_bow, y_tip),
        (shoulder_x, -to_port),
        (-to_stern, -to_port),
        (-to_stern, to_starboard),
        (shoulder_x, to_starboard),
    ])
    return convex_outline(points)


#: where along the hull, as a share of its length from each end, the ends' widths are read
END_SHARE = 0.1
#: the bow end (+x) this much wider than the stern end at END_SHARE reads as a stern
BLUNT_BOW_RATIO = 1.25


def end_widths(outline: np.ndarray) -> tuple[float, float]:
    """The outline's width (m, across x) at :data:`END_SHARE` of its length in from the bow
    (+x) end and from the stern (-x) end."""
    polygon = Polygon(outline)
    x_min, y_min, x_max, y_max = polygon.bounds
    step = END_SHARE * (x_max - x_min)

    def width(x: float) -> float:
        return float(polygon.intersection(shapely.LineString([(x, y_min - 1.0), (x, y_max + 1.0)])).length)

    return width(x_max - step), width(x_min + step)


def bow_looks_aft(outline: np.ndarray) -> str | None:
    """A note when the mesh's bow end (+x in V, as ``mesh_axes`` put it) is clearly blunter
    than its stern end: most hulls narrow toward the bow and end square or round at the
    stern, so a mesh whose x axis runs aft (a CAD model's convention) given as
    ``[bow, ...]`` shows a full end at +x. Then every section is mislabelled (section 0
    reads the stern's water) and, on a hull nearly alike at both ends, nothing in the image
    tells. None for a hull whose ends are alike (a barge, a double-ended ferry) or whose bow
    is the narrower."""
    bow_m, stern_m = end_widths(outline)
    if bow_m > BLUNT_BOW_RATIO * stern_m:
        return (f"the hull is {bow_m:.1f} m wide {100 * END_SHARE:.0f} % in from its bow end (+x) "
                f"and {stern_m:.1f} m from its stern end: is the bow at -x? A mesh whose x "
                "axis runs aft is given as [stern, ...]")
    return None
