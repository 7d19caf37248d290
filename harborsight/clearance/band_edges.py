"""Obstacle candidates at the boundaries between the sections' bands.

A section takes the obstacle points its band holds (:mod:`harborsight.clearance.measure`);
at the boundary ray between two neighbouring bands a point may belong to either. Two kinds
of candidate are added there: where a contour crosses the boundary ray (:func:`band_crossings`,
with the obstacle edge's direction, which decides how far the crossing slides when the hull
turns), and contour pixels whose square, not only its centre, reaches into the neighbouring
band (:func:`band_edge_pixels`), so that an obstacle corner poking less than a pixel into a
band is not missed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harborsight.vessel.sections import SectionedOutline


@dataclass(frozen=True)
class Candidates:
    """Obstacle points with their section, distance and nearest hull point; a crossing
    of a band's boundary ray also carries the obstacle edge's direction there (pixels; zero
    for any other point), which decides how far the crossing slides when the hull turns."""

    section: np.ndarray
    distance: np.ndarray
    nearest: np.ndarray
    points_px: np.ndarray
    contact: np.ndarray
    on_border: np.ndarray
    edge_px: np.ndarray

    @classmethod
    def empty(cls) -> Candidates:
        none = np.zeros(0)
        return cls(none.astype(int), none, np.zeros((0, 2)), np.zeros((0, 2)),
                   none.astype(bool), none.astype(bool), np.zeros((0, 2)))

    @classmethod
    def joined(cls, *parts: Candidates) -> Candidates:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__dataclass_fields__))


def band_crossings(
    outline: SectionedOutline, points: np.ndarray, points_px: np.ndarray,
    section: np.ndarray, contours,
) -> Candidates:
    """Where a contour crosses the boundary ray between two neighbouring sections.

    Contour pixels are discrete, so the exact point where an obstacle's border enters a
    band would be missed by up to a pixel along the border. For consecutive contour points
    ``p`` (section a) and ``q`` (section b = a ± 1) we intersect the segment with the ray
    ``B + s·d`` at their shared break ``B`` and give the crossing ``X`` to both sections;
    its nearest hull point is ``B`` itself.
    """
    n = outline.n_sections
    nxt = contours.next_index
    a, b = section, section[nxt] if len(nxt) else section
    forward = (a >= 0) & (b == (a + 1) % n)
    backward = (b >= 0) & (a == (b + 1) % n)
    pair = np.flatnonzero((forward | backward) & (a != b))
    if len(pair) == 0:
        return Candidates.empty()
    k = np.where(forward[pair], b[pair], a[pair])
    p, q = points[pair], points[nxt[pair]]
    origin, ray = outline.break_points[k], outline.break_ray[k]
    seg = q - p
    rhs = origin - p
    det = -seg[:, 0] * ray[:, 1] + seg[:, 1] * ray[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-rhs[:, 0] * ray[:, 1] + rhs[:, 1] * ray[:, 0]) / det
    t = np.clip(t, 0.0, 1.0)
    t[np.isnan(t)] = 0.0
    cross = p + t[:, None] * seg
    cross_px = points_px[pair] + t[:, None] * (points_px[nxt[pair]] - points_px[pair])
    dist = np.hypot(*(cross - origin).T)
    contact = contours.contact[pair] | contours.contact[nxt[pair]]
    border = contours.on_border[pair] | contours.on_border[nxt[pair]]

    def twice(first: np.ndarray, second: np.ndarray | None = None) -> np.ndarray:
        return np.concatenate((first, first if second is None else second))

    return Candidates(
        section=twice(a[pair], b[pair]), distance=twice(dist), nearest=twice(origin),
        points_px=twice(cross_px), contact=twice(contact), on_border=twice(border),
        edge_px=twice(_contour_direction_px(contours, pair, nxt[pair])),
    )


#: contour steps each way over which an obstacle edge's direction is taken (a pixel
#: staircase's single step is off by up to 45 degrees; over ten, by about 6)
_EDGE_STEPS = 10


def _contour_direction_px(contours, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """The contour's direction (pixels) over the stretch from :data:`_EDGE_STEPS` points
    before ``first`` to as many after ``last`` (``first == last`` for one point)."""
    nxt, previous = contours.next_index, contours.previous_index
    ahead, behind = np.asarray(last).copy(), np.asarray(first).copy()
    for _ in range(_EDGE_STEPS):
        ahead, behind = nxt[ahead], previous[behind]
    points_px = contours.points_px.astype(float)
    return points_px[ahead] - points_px[behind]


#: how many contour steps from a band's boundary ray a section's nearest point may lie and
#: still be where the obstacle edge leaves the band
_ON_RAY_STEPS = 3.0


def beside_a_boundary_ray(outline: SectionedOutline, points: np.ndarray, idx: np.ndarray,
                           section: np.ndarray, distance: np.ndarray, contours
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Which of the contour points ``idx`` (each its band's nearest) are where the obstacle
    edge leaves the band across a boundary ray, as a crossing is, and the contour's
    direction there (pixels, from the point before to the one after): within
    :data:`_ON_RAY_STEPS` contour steps of one of the band's two boundary rays, with the
    contour going on nearer to the hull across it (a pixel staircase puts the band's
    nearest pixel up to a few pixels short of the ray). A turn of the hull slides such a
    point along the edge; a nearest point the edge curves away from on both sides (a
    corner, a bend) stays. ``section`` and ``distance``: every contour point's band and
    distance to its own nearest hull point."""
    if len(idx) == 0 or outline.n_sections < 2:
        return np.zeros(len(idx), bool), np.zeros((0, 2))
    nxt, previous = contours.next_index, contours.previous_index
    ahead, behind = nxt[idx], previous[idx]
    step = np.maximum(np.hypot(*(points[ahead] - points[idx]).T),
                      np.hypot(*(points[idx] - points[behind]).T))
    own = section[idx]
    near = np.zeros(len(idx), bool)
    for k in (own, (own + 1) % outline.n_sections):
        near |= _near_ray(points[idx], outline.break_points[k], outline.break_ray[k],
                          _ON_RAY_STEPS * step)
    # the contour, a few steps each way: nearer to the hull in another band
    nearer_across = np.zeros(len(idx), bool)
    for walk in (nxt, previous):
        at = idx.copy()
        for _ in range(int(2 * _ON_RAY_STEPS) + 2):
            at = walk[at]
            nearer_across |= (section[at] >= 0) & (section[at] != own) & (distance[at] < distance[idx])
    near &= nearer_across
    return near, _contour_direction_px(contours, idx[near], idx[near])


_BAND_EDGE_PENALTY_PX = 2.0
_TIP_STEPS = 3
_NEAR_RAY_STEPS = 1.5
_PIXEL_CORNERS = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])


def _side_of_ray(points: np.ndarray, origin: np.ndarray, ray: np.ndarray) -> np.ndarray:
    """Signed distance of points from the line ``origin + s·ray`` (unit ``ray``)."""
    rel = points - origin
    return rel[:, 0] * ray[:, 1] - rel[:, 1] * ray[:, 0]


def _near_ray(points: np.ndarray, origin: np.ndarray, ray: np.ndarray,
              reach: np.ndarray) -> np.ndarray:
    """Points within ``reach`` of the ray ``origin + s·ray, s >= 0`` (not of its whole line:
    with two sections, a box's two break rays lie on one line)."""
    along = np.einsum("ij,ij->i", points - origin, ray)
    return (np.abs(_side_of_ray(points, origin, ray)) <= reach) & (along >= -reach)


def band_edge_pixels(
    outline: SectionedOutline, to_outline, points: np.ndarray, points_px: np.ndarray,
    section: np.ndarray, contours,
) -> Candidates:
    """Contour pixels whose square reaches into a neighbouring section's band.

    A contour point is a pixel centre, but the solid pixel covers its whole square: an
    obstacle corner that enters section b's band by less than a pixel leaves every contour
    centre in band a = b ± 1, and section b would see nothing there. Each contour pixel's
    four corners are mapped like the centres (``to_outline``); when one of them falls in a
    neighbouring band b, the pixel is also a candidate of b, at its foot on the break ray
    ``B + s·r`` they share (distance ``s = (p - B)·r``, nearest hull point ``B``).

    Whether the obstacle really crosses is beyond a binary mask (an edge running along the
    ray within half a pixel looks the same), so only tips count: the contour, ``_TIP_STEPS``
    points before and after, is farther from the ray by more than half a pixel. And they
    rank as if ``_BAND_EDGE_PENALTY_PX`` pixels farther: they win only where the band's own
    points are farther still, i.e. where missing the sliver would cost more than a few
    pixels. The reported distance is the pixel's own (with the boundary correction), not
    the penalty.
    """
    n = outline.n_sections
    if n < 2:
        return Candidates.empty()
    # cheap pre-filter before mapping corners: only points within about a pixel of one of
    # their section's two boundary rays can have a corner across it. A pixel's extent in the
    # outline's units is bounded from the steps to its contour neighbours (1 or 1.4 px each)
    previous = contours.previous_index
    step_ahead = np.hypot(*(points[contours.next_index] - points).T)
    step_size = np.maximum(step_ahead, step_ahead[previous])   # the step back: previous's ahead
    own_all = np.maximum(section, 0)
    near_ray = np.zeros(len(points), bool)
    for k in (own_all, (own_all + 1) % n):
        near_ray |= _near_ray(points, outline.break_points[k], outline.break_ray[k],
                              _NEAR_RAY_STEPS * step_size)
    candidate = np.flatnonzero((section >= 0) & near_ray)
    if len(candidate) == 0:
        return Candidates.empty()
    corners_px = (points_px[candidate, None, :] + _PIXEL_CORNERS).reshape(-1, 2)
    corners, corners_valid = to_outline(corners_px)
    corner_section = np.where(corners_valid, outline.assign(
        np.where(corners_valid[:, None], corners, 0.0)).section, -1).reshape(-1, 4)
    own = section[candidate]
    chosen, neighbour, shared_break = [], [], []
    for step, break_of in ((1, (own + 1) % n), (-1, own)):
        other = (own + step) % n
        # near this break's own ray: with two sections both breaks separate the same pair
        # of bands, and only the ray the pixel straddles is the one it reaches across
        near_this_ray = _near_ray(points[candidate], outline.break_points[break_of],
                                  outline.break_ray[break_of],
                                  _NEAR_RAY_STEPS * step_size[candidate])
        reaches = (np.any(corner_section == other[:, None], axis=1) & (other != own)
                   & near_this_ray)
        chosen.append(candidate[reaches])
        neighbour.append(other[reaches])
        shared_break.append(break_of[reaches])
    idx, b, k = (np.concatenate(v) for v in (chosen, neighbour, shared_break))
    origin, ray = outline.break_points[k], outline.break_ray[k]
    along = np.maximum(np.einsum("ij,ij->i", points[idx] - origin, ray), 0.0)
    # the pixel's size where it lies (mean diagonal / sqrt 2), in the outline's units
    square = corners.reshape(-1, 4, 2)[np.searchsorted(candidate, idx)]
    pixel_size = 0.5 * (np.hypot(*(square[:, 2] - square[:, 0]).T)
                        + np.hypot(*(square[:, 3] - square[:, 1]).T)) / 2 ** 0.5
    # only tips: the contour must recede from the ray on both sides (an edge that runs along
    # the ray is not a corner entering the band)
    def side_distance(i: np.ndarray) -> np.ndarray:
        return _side_of_ray(points[i], origin, ray)
    own_side = np.sign(side_distance(idx))
    ahead, behind = idx.copy(), idx.copy()
    for _ in range(_TIP_STEPS):
        ahead, behind = contours.next_index[ahead], previous[behind]
    depth = own_side * side_distance(idx) + 0.5 * pixel_size
    tip = ((own_side * side_distance(ahead) > depth)
           & (own_side * side_distance(behind) > depth))
    idx, b, origin, along, pixel_size = idx[tip], b[tip], origin[tip], along[tip], pixel_size[tip]
    return Candidates(
        section=b, distance=along + _BAND_EDGE_PENALTY_PX * pixel_size, nearest=origin,
        points_px=points_px[idx],
        contact=contours.contact[idx], on_border=contours.on_border[idx],
        edge_px=np.zeros((len(idx), 2)),      # a corner's tip: it does not slide along an edge
    )
