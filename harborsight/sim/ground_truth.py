"""Exact per-section ground truth on the water plane, with shapely.

Independent of the measuring code's band assignment: each section's band is built here as
an explicit polygon from rays (perpendicular to each edge, along the bisector where two
sections meet at a corner) and intersected with the obstacle footprints.
"""

from __future__ import annotations

from itertools import pairwise

import cv2
import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon

from harborsight.frame import FrameGeometry
from harborsight.geometry.camera import image_border_px, ray_edge_px
from harborsight.vessel.sections import SectionedOutline
from harborsight.vessel.spec import VesselSpec

BAND_REACH_M = 5_000.0


def _outward_normal(direction: np.ndarray, positive: bool) -> np.ndarray:
    d = direction / np.linalg.norm(direction)
    n = np.array([d[1], -d[0]])
    return n if positive else -n


def section_band_polygon(outline: SectionedOutline, k: int, reach: float = BAND_REACH_M) -> Polygon:
    """Region outside the hull whose nearest hull point lies on section k (a polygon)."""
    poly = outline.section_polyline(k)
    ring = outline.vertices
    x, y = ring[:, 0], ring[:, 1]
    positive = float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)) > 0
    seg_normals = [_outward_normal(b - a, positive) for a, b in pairwise(poly)
                   if np.linalg.norm(b - a) > 1e-12]
    # normals of the outline just before the section's start and just after its end, where
    # the break is a corner (as section_polyline decides it); a break on an edge's inside,
    # even a hair past a corner, starts its band square to that edge (the corner's wedge is
    # the section before's: sampled across it, two bands overlapped, a truth 0.1 m short)
    eps = 1e-6 * outline.perimeter
    pos_a = outline.break_position[k]
    pos_b = outline.break_position[k + 1] if k + 1 < outline.n_sections else outline.perimeter
    n_before, n_after = seg_normals[0], seg_normals[-1]
    if outline.break_on_corner[k]:
        before = outline.points_at(np.array([pos_a - 2 * eps, pos_a - eps]))
        n_before = _outward_normal(before[1] - before[0], positive)
    if outline.break_on_corner[(k + 1) % outline.n_sections]:
        after = outline.points_at(np.array([pos_b + eps, pos_b + 2 * eps]))
        n_after = _outward_normal(after[1] - after[0], positive)
    start_ray = n_before + seg_normals[0]
    end_ray = seg_normals[-1] + n_after
    outer = [poly[0] + reach * start_ray / np.linalg.norm(start_ray)]
    for i in range(1, len(poly) - 1):
        outer.append(poly[i] + reach * seg_normals[i - 1])
        outer.append(poly[i] + reach * seg_normals[i])
    outer.append(poly[-1] + reach * end_ray / np.linalg.norm(end_ray))
    boundary = [poly[0], *outer, *poly[::-1][:-1]]
    band = Polygon(boundary)
    return band if band.is_valid else shapely.make_valid(band)


def section_distances(
    outline: SectionedOutline, obstacles: shapely.Geometry, visible: shapely.Geometry | None
) -> list[dict[str, float | None]]:
    """Per section: distance (m) to obstacles in its band, within ``visible`` and overall."""
    results = []
    for k in range(outline.n_sections):
        band = section_band_polygon(outline, k)
        line = LineString(outline.section_polyline(k))
        in_band = shapely.intersection(band, obstacles)
        d_all = None if in_band.is_empty else float(shapely.distance(line, in_band))
        d_vis = None
        if visible is not None and not in_band.is_empty:
            seen = shapely.intersection(in_band, visible)
            d_vis = None if seen.is_empty else float(shapely.distance(line, seen))
        results.append({"index": k, "distance_m": d_vis, "distance_all_m": d_all})
    return results


def vessel_silhouette_px(vessel: VesselSpec, geometry: FrameGeometry) -> list[np.ndarray]:
    """The vessel's image as convex polygons (pixels), one per layer
    (:attr:`VesselSpec.own_layers`): each layer's convex hull projected, edges followed
    through the lens distortion (:meth:`Camera.project_convex_outline`); their union is
    the silhouette. Layers that do not project are left out."""
    polygons = []
    for uv in geometry.camera.project_convex_outlines([geometry.vessel_to_enu(layer)
                                                       for layer in vessel.own_layers]):
        if len(uv) >= 3:
            polygons.append(cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2).astype(float))
    return polygons


def vessel_silhouette(vessel: VesselSpec, geometry: FrameGeometry) -> Polygon | MultiPolygon:
    """The union of :func:`vessel_silhouette_px`'s polygons (pixels)."""
    return shapely.union_all([Polygon(p).buffer(0) for p in vessel_silhouette_px(vessel, geometry)])


def image_ground_polygon(geometry: FrameGeometry, samples_per_side: int = 64) -> Polygon:
    """The part of the water plane the image samples: the outline of its pixel centres,
    back-projected (what a mask can show, so frame-cut obstacles compare like for like).
    Where a barrel lens's fold lies inside the image, the outline follows the edge of the
    pixels with a ray (:func:`~harborsight.geometry.camera.ray_edge_px`), as the clearance
    step does: the image's border alone counted the water past the fold as seen."""
    intr = geometry.camera.intrinsics
    loop = ray_edge_px(intr)
    if loop is not None:
        ground, valid = geometry.camera.back_project_to_plane(loop)
        return Polygon(ground[valid, :2]).buffer(0) if valid.sum() >= 3 else Polygon()
    border = image_border_px(intr.width, intr.height, samples_per_side)
    ground, valid = geometry.camera.back_project_to_plane(border)
    return Polygon(ground[valid, :2]).buffer(0)


#: where the plain union loses a part, footprints are unioned again on this grid (metres)
FOOTPRINT_GRID_M = 1e-6


def footprint_union(polygons) -> Polygon | MultiPolygon:
    """The union of water-plane footprints, robust to parts that share edges.

    GEOS's floating-point overlay can drop whole pieces where many parts share edges to
    within rounding (a shore of 24 slabs lost 17 % of its land). Every polygon of every
    input keeps a point of its interior in a correct union; when one does not, the union is made again with
    the fixed-precision overlay on a :data:`FOOTPRINT_GRID_M` grid (which moves no vertex
    by more than half a micrometre, and costs about four times as much).
    """
    polygons = [p for p in polygons if not p.is_empty]
    union = shapely.union_all(polygons)
    if len(polygons) > 1:
        # one interior point per polygon of every input (an object's footprint may be several)
        inner = shapely.point_on_surface(shapely.get_parts(polygons))
        if not shapely.contains_xy(union, shapely.get_x(inner), shapely.get_y(inner)).all():
            union = shapely.union_all(polygons, grid_size=FOOTPRINT_GRID_M)
    return union


def frame_ground_truth(
    geometry: FrameGeometry, vessel: VesselSpec, footprints_enu: list[Polygon],
    n_sections: int | None = None,
) -> list[dict[str, float | None]]:
    """design.md ``ground_truth`` sections for obstacle footprints (ENU water-plane polygons).

    ``distance_m`` counts only the parts of footprints that the image shows on the water
    plane (inside the back-projected frame, outside the vessel's own silhouette);
    ``distance_all_m`` counts every obstacle.
    """
    to_vessel = _to_vessel_frame(geometry)
    obstacles = footprint_union([to_vessel(p) for p in footprints_enu])
    return section_distances(vessel.sections(n_sections), obstacles,
                             to_vessel(visible_water_plane(geometry, vessel)))


def visible_water_plane(geometry: FrameGeometry, vessel: VesselSpec) -> Polygon:
    """ENU polygon of the water plane the image shows beside the vessel: the back-projected
    frame minus the vessel's own silhouette."""
    seen = image_ground_polygon(geometry)
    for polygon_px in vessel_silhouette_px(vessel, geometry):
        hidden_ground, ok = geometry.camera.back_project_to_plane(polygon_px)
        if ok.all():
            seen = seen.difference(Polygon(hidden_ground[:, :2]).buffer(0))
    return seen


def nearest_visible_obstacle(
    geometry: FrameGeometry, vessel: VesselSpec, footprints_enu: list[Polygon],
    n_sections: int | None = None,
) -> list[int | None]:
    """Per section, the index in ``footprints_enu`` of the obstacle that its ``distance_m``
    (see :func:`frame_ground_truth`) is measured to; ``None`` where none is in view."""
    to_vessel = _to_vessel_frame(geometry)
    sections = vessel.sections(n_sections)
    seen = to_vessel(visible_water_plane(geometry, vessel))
    footprints = [to_vessel(p) for p in footprints_enu]
    nearest: list[int | None] = []
    for k in range(sections.n_sections):
        band = shapely.intersection(section_band_polygon(sections, k), seen)
        line = LineString(sections.section_polyline(k))
        best, best_m = None, np.inf
        for i, footprint in enumerate(footprints):
            part = shapely.intersection(band, footprint)
            if not part.is_empty and (d := float(shapely.distance(line, part))) < best_m:
                best, best_m = i, d
        nearest.append(best)
    return nearest


def _to_vessel_frame(geometry: FrameGeometry):
    def transform(poly: Polygon) -> Polygon:
        return shapely.transform(poly, geometry.enu_to_vessel_xy)
    return transform
