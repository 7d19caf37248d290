"""Whole-image search for the hull: where the image itself puts the vessel.

The refinement (:mod:`harborsight.clearance.pose_refinement`) corrects the sensors' pose
within their prior: 12 m, 12 degrees, 4 m of height. Real logs also hold gross errors: a
stale or wrong-antenna fix (tens of metres), an ellipsoidal height read as height above the
water (20-50 m in Europe), a course over ground taken for the heading while the vessel goes
astern (180 degrees). Then the refinement's outline lies on water and finds nothing, or it
fits a wrong correction: an outline too small for the ship nestles into a corner of its
pixels, where the points deep inside cannot tell. The distances are then wrong with
nothing said (docs/results.md).

**Hypotheses from the ship blobs.** The mask's largest ship regions (their outer contours,
at least :data:`MIN_BLOB_SHARE` of the predicted silhouette's area) each give poses that lay
the silhouette on the blob: its scale from the blob's length and area against the predicted
silhouette's (``s``, the height becoming ``H / s`` for a camera ``H`` above the water), its
heading from the blob's principal axis (both ways along it) or the sensors' heading (both
ways), and its position by moving the silhouette's centroid onto the blob's. The principal
axis of a region with central moments ``mu20, mu02, mu11`` is at
``theta = atan2(2 mu11, mu20 - mu02) / 2``, and its length along that axis is taken as
``sqrt(12 lambda_1)`` (a uniform bar of length ``L`` has variance ``L^2 / 12``).

**Verification.** Each start is scored by the Tukey cost of its outline at the refinement's
wide scale, and the best :data:`VERIFY_STARTS` are fitted by the same Gauss-Newton with a
flat prior, on the signed distance of the whole image. A placement is described by its
**edge share**, the share of its outline's points in view within
:data:`~harborsight.clearance.alignment.INLIER_PX` of a ship edge. Unlike the
refinement's inlier fraction, points deep inside ship pixels count against it: a right
placement has its whole outline on the ship's edge unless a neighbour touches it, while a
shrunken outline in a corner of a large ship has half its points deep inside.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from harborsight.clearance.alignment import (
    INLIER_PX,
    MIN_EDGE_POINTS,
    SCHEDULES,
    Alignment,
    SignedDistance,
    Silhouette,
    gauss_newton,
    outline_fit,
    ship_fill,
    tukey_cost,
)
from harborsight.frame import FrameGeometry

#: at most this many blobs, the largest, give hypotheses
MAX_BLOBS = 3
#: a blob smaller than this share of the predicted silhouette's area gives none (a height
#: off by a factor of three shrinks the ship's area ninefold)
MIN_BLOB_SHARE = 0.08
#: scales (predicted to seen) outside this range are not tried
SCALE_RANGE = (0.3, 3.0)
#: a drone lower than this above the water is not a hypothesis
MIN_HEIGHT_M = 3.0
#: how many of the starts, the cheapest, are fitted
VERIFY_STARTS = 4
#: the sliding search (:func:`_sliding_starts`): its field is truncated at this many pixels,
#: it runs on the image scaled by this factor, and this many minima per heading are starts
SLIDE_TRUNCATE_PX = 8.0
SLIDE_SCALE = 0.5
SLIDE_STARTS = 3
#: a silhouette whose outline spans more than this many image widths or heights is not slid:
#: wherever it lies, under about half of its outline is in view, and a placement must have
#: most of it in view; its kernel, drawn at that size, would not fit in memory (a box hull
#: 57 degrees off nadir reached toward the horizon: 49 GiB for the correlation)
SLIDE_MAX_EXTENT = 2.0
#: how many of the sliding starts, the cheapest, are fitted besides the others
VERIFY_SLIDING = 2
#: at most this many outline points (every k-th) score a start
START_POINTS = 80
#: a filled placement with this edge share and at most one gross error ends the verification
CLEAR_FIT_SHARE = 0.95
#: the Tukey scale (px) the starts are scored at: the refinement's second schedule's first
START_TUKEY_PX = SCHEDULES[1][0][1]
#: one sigma of the search's prior, (m, m, rad, m): flat over any placement in the image
FLAT_PRIOR_SIGMA = np.array([1e3, 1e3, 1e3, 1e3])


@dataclass(frozen=True)
class Placement:
    """Where the image puts the hull: ``params`` ``(de, dn, dpsi, dh)`` from the sensors'
    pose, and the fit there."""

    params: np.ndarray
    edge_share: float
    inlier_fraction: float
    residual_px: float | None
    ship_fill: float
    in_view: float
    edge_points: int


def edge_share(value: np.ndarray) -> float:
    """Share of an outline's points in view (their signed distances ``value``) within
    ``INLIER_PX`` of a ship edge; 0 for none in view."""
    return float(np.count_nonzero(np.abs(value) <= INLIER_PX) / len(value)) if len(value) else 0.0


def whole_image_alignment(labels_ship: np.ndarray, geometry: FrameGeometry) -> Alignment:
    """An alignment on the signed distance of the whole image's ship pixels."""
    return Alignment(geometry, SignedDistance(labels_ship, (0, 0)))


def silhouette_overlap(uv_a: np.ndarray, uv_b: np.ndarray) -> float:
    """The area two silhouettes (convex hulls of the hull points' pixels ``(N, 2)``, NaN
    where they do not project) share, as a share of the smaller one's; 0 when either has
    no area."""
    hulls = []
    for uv in (uv_a, uv_b):
        uv = uv[np.isfinite(uv).all(axis=1)]
        if len(uv) < 3:
            return 0.0
        hulls.append(cv2.convexHull(uv.astype(np.float32)))
    smaller = min(cv2.contourArea(h) for h in hulls)
    if smaller <= 0:
        return 0.0
    shared, _ = cv2.intersectConvexConvex(hulls[0], hulls[1])
    return float(shared) / smaller


def _region(polygon: np.ndarray) -> tuple[float, np.ndarray, float, float] | None:
    """``(area px, centroid (2,), axis angle rad, length px)`` of a filled polygon ``(N, 2)``,
    from its moments (module docstring); None for no area."""
    m = cv2.moments(polygon.astype(np.float32))
    area = m["m00"]
    if area <= 0:
        return None
    centroid = np.array([m["m10"] / area, m["m01"] / area])
    mu20, mu02, mu11 = m["mu20"] / area, m["mu02"] / area, m["mu11"] / area
    angle = 0.5 * math.atan2(2 * mu11, mu20 - mu02)
    major = 0.5 * (mu20 + mu02) + math.sqrt(0.25 * (mu20 - mu02) ** 2 + mu11 ** 2)
    return area, centroid, angle, math.sqrt(12 * major)


def _silhouette(align: Alignment, silhouette: Silhouette, params: np.ndarray
                ) -> tuple[float, np.ndarray, float, float] | None:
    """The projected silhouette's region (:func:`_region`) under ``params``: the convex
    hull of all its layers' points (a start's coarse measures)."""
    uv = align.pixels(silhouette.points_h, params)
    uv = uv[np.isfinite(uv).all(axis=1)]
    if len(uv) < 3:
        return None
    return _region(cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2))


def _wrap_axis(angle: float) -> float:
    """An axis angle (defined modulo pi) in ``[-pi/2, pi/2)``."""
    return (angle + math.pi / 2) % math.pi - math.pi / 2


def _centroid_jacobian(align: Alignment, silhouette: Silhouette
                       ) -> tuple[tuple[float, np.ndarray, float, float], np.ndarray] | None:
    """The predicted silhouette's region (:func:`_region`) at the sensors' pose and its
    centroid's Jacobian in the shift (pixels per metre, columns east and north), from
    projections 1 m east and 1 m north; None when either fails or it is singular."""
    predicted = _silhouette(align, silhouette, np.zeros(4))
    east = _silhouette(align, silhouette, np.array([1.0, 0.0, 0.0, 0.0]))
    north = _silhouette(align, silhouette, np.array([0.0, 1.0, 0.0, 0.0]))
    if predicted is None or east is None or north is None:
        return None
    jacobian = np.column_stack((east[1] - predicted[1], north[1] - predicted[1]))
    if abs(np.linalg.det(jacobian)) < 1e-9:
        return None
    return predicted, jacobian


def _starts(align: Alignment, silhouette: Silhouette, ship: np.ndarray) -> list[np.ndarray]:
    """Poses ``(de, dn, dpsi, dh)`` that lay the silhouette on the largest ship blobs. The
    shift puts the silhouette's centroid on the blob's in one Newton step, with the
    centroid's Jacobian in the shift taken at the sensors' pose from projections 1 m east
    and 1 m north and scaled by ``H / (H + dh)`` (pixels per metre go as one over the
    range); the silhouette moves as a whole, so the Jacobian holds for any heading."""
    found = _centroid_jacobian(align, silhouette)
    height_m = float(align.camera.position_enu[2])
    if found is None or height_m <= 0:
        return []
    (area_pred, _, angle_pred, length_pred), jacobian = found
    turned = _silhouette(align, silhouette, np.array([0.0, 0.0, 0.2, 0.0]))
    # +1 when the image axis turns with the heading, -1 when against it (a mirrored view)
    sense = 1.0 if turned is None or _wrap_axis(turned[2] - angle_pred) >= 0 else -1.0
    # the blobs' outer contours (8-connected; holes filled): their polygons' moments are a
    # tenth of the cost of labelling the components
    contours, _ = cv2.findContours(ship.view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    blobs = [blob for blob in (_region(c.reshape(-1, 2)) for c in contours if len(c) >= 3)
             if blob is not None and blob[0] >= MIN_BLOB_SHARE * area_pred]
    centroids: dict[tuple[float, float], np.ndarray | None] = {}    # of the silhouette, by pose
    starts: list[np.ndarray] = []
    for area, centroid, angle, length in sorted(blobs, key=lambda b: -b[0])[:MAX_BLOBS]:
        scales: list[float] = []
        for scale in (1.0, length / length_pred, math.sqrt(area / area_pred)):
            scale = min(max(scale, SCALE_RANGE[0]), SCALE_RANGE[1])
            if all(abs(scale / other - 1) > 0.1 for other in scales):
                scales.append(scale)
        turns: list[float] = []
        for turn in (sense * _wrap_axis(angle - angle_pred), 0.0):
            for flip in (0.0, math.pi):
                turn_rad = (turn + flip + math.pi) % (2 * math.pi) - math.pi
                if all(abs((turn_rad - t + math.pi) % (2 * math.pi) - math.pi) > math.radians(15)
                       for t in turns):
                    turns.append(turn_rad)
        for scale in scales:
            dh = height_m / scale - height_m
            if height_m + dh < MIN_HEIGHT_M:
                continue
            for turn in turns:
                key = (round(turn, 6), round(dh, 6))
                if key not in centroids:
                    here = _silhouette(align, silhouette, np.array([0.0, 0.0, turn, dh]))
                    centroids[key] = None if here is None else here[1]
                if centroids[key] is None:
                    continue
                shift = np.linalg.solve(jacobian * scale, centroid - centroids[key])
                if np.isfinite(shift).all():
                    starts.append(np.array([shift[0], shift[1], turn, dh]))
    return starts


def _sliding_starts(align: Alignment, silhouette: Silhouette, beyond_m: float = 0.0) -> list[np.ndarray]:
    """Poses ``(de, dn, dpsi, 0)`` that slide the predicted silhouette, at the sensors'
    heading and reversed and at their scale, to where its outline lies best along ship
    edges anywhere in the image: a chamfer match. The blob starts lay the silhouette's
    centroid on a blob's, which misses a vessel moored against another (one blob, its
    centroid between the two hulls).

    With ``f = min(|s|, T)`` the signed distance's magnitude truncated at
    :data:`SLIDE_TRUNCATE_PX` (``T`` beyond the image), the cost of a translation ``t`` is
    ``sum_k f(x_k + t)`` over the outline's points ``x_k`` relative to the silhouette's
    centroid: one correlation of ``f`` with the points drawn as a kernel gives it for every
    ``t`` at once (on the image scaled by :data:`SLIDE_SCALE`). The
    :data:`SLIDE_STARTS` lowest minima, at least half the silhouette's length apart, each
    give a shift through the centroid's Jacobian (pixels per metre at the sensors' pose);
    shifts under ``beyond_m`` are left to the refinement, whose reach they are within (at
    150 m a poor mask's blob near the pose took a shrunk hull there for a height error)."""
    predicted = _centroid_jacobian(align, silhouette)
    if predicted is None:
        return []
    jacobian = predicted[1]
    field = np.minimum(np.abs(align.sdf.field), np.float32(SLIDE_TRUNCATE_PX))
    small = cv2.resize(field, None, fx=SLIDE_SCALE, fy=SLIDE_SCALE, interpolation=cv2.INTER_AREA)
    origin = np.array([align.sdf.u0, align.sdf.v0], float)
    starts: list[np.ndarray] = []
    for turn in (0.0, math.pi):
        params = np.array([0.0, 0.0, turn, 0.0])
        region = _silhouette(align, silhouette, params)
        if region is None:
            continue
        outline = silhouette.outline(align.pixels(silhouette.points_h, params))
        uv = align.pixels(outline, params)
        uv = uv[np.isfinite(uv).all(axis=1)]
        if len(uv) < MIN_EDGE_POINTS:
            continue
        offsets = np.rint((uv - region[1]) * SLIDE_SCALE).astype(int)
        low = offsets.min(axis=0)
        if (low > 0).any() or (offsets.max(axis=0) < 0).any():
            continue        # the centroid off its own outline's box: no anchor for it
        if (offsets.max(axis=0) - low + 1 > SLIDE_MAX_EXTENT * np.array(small.shape[::-1])).any():
            continue        # far larger than the image: no slide puts most of it in view
        kernel = np.zeros(tuple(offsets.max(axis=0) - low + 1)[::-1], np.float32)
        np.add.at(kernel, (offsets[:, 1] - low[1], offsets[:, 0] - low[0]), 1.0)
        kernel /= len(offsets)
        # pad with T so that points off the image count as outliers; correlate; crop
        pad_y, pad_x = kernel.shape
        padded = cv2.copyMakeBorder(small, pad_y, pad_y, pad_x, pad_x, cv2.BORDER_CONSTANT,
                                    value=SLIDE_TRUNCATE_PX)
        cost = cv2.filter2D(padded, cv2.CV_32F, kernel, anchor=(int(-low[0]), int(-low[1])),
                            borderType=cv2.BORDER_CONSTANT)[pad_y:-pad_y, pad_x:-pad_x]
        radius = max(1.0, 0.5 * region[3] * SLIDE_SCALE)
        rows, cols = np.indices(cost.shape)
        for _ in range(SLIDE_STARTS):
            y, x = np.unravel_index(int(np.argmin(cost)), cost.shape)
            if not np.isfinite(cost[y, x]) or cost[y, x] >= SLIDE_TRUNCATE_PX:
                break
            cost[(rows - y) ** 2 + (cols - x) ** 2 <= radius ** 2] = np.inf
            target = (np.array([x, y], float) + 0.5) / SLIDE_SCALE - 0.5 + origin
            shift = np.linalg.solve(jacobian, target - region[1])
            if np.isfinite(shift).all() and math.hypot(*shift) >= beyond_m:
                starts.append(np.array([shift[0], shift[1], turn, 0.0]))
    return starts


def _start_cost(align: Alignment, outline: np.ndarray, params: np.ndarray) -> float:
    """Tukey's cost at :data:`START_TUKEY_PX` per outline point under ``params`` (points out
    of view count as outliers)."""
    value = align.residuals(outline, params)
    out_of_view = outline.shape[1] - len(value)
    cost = tukey_cost(value, START_TUKEY_PX).sum() + out_of_view * START_TUKEY_PX ** 2 / 6
    return float(cost) / outline.shape[1]


def place_hull(align: Alignment, silhouette: Silhouette, ship: np.ndarray, known: np.ndarray,
               edge_weight: float = 1.0, min_ship_fill: float = 0.9,
               against: np.ndarray | None = None, extra_starts: tuple[np.ndarray, ...] = (),
               slide: bool = False, slide_beyond_m: float = 0.0,
               gross_errors: Callable[[np.ndarray], int] | None = None,
               count_share: float = 0.8) -> Placement | None:
    """The best placement of the hull on the image's ship blobs (module docstring): among
    those whose silhouette is at least ``min_ship_fill`` ship pixels if any, the highest edge
    share (then the lowest fitted cost); None when no start fits. With ``gross_errors`` (how
    many gross errors a correction holds), among the filled placements with at least
    ``count_share`` edge share the one with the fewest comes first. A fit whose height leaves
    :data:`SCALE_RANGE` is dropped. With ``against`` (the pose kept or applied), only starts
    whose outline costs less than the outline does at ``against`` (Tukey at
    :data:`START_TUKEY_PX`) are fitted: a
    vessel moored against another leaves a third of its outline deep in ship pixels, and
    the search then ran on every frame of it for nothing. ``extra_starts`` join the blobs'
    starts (the refinement's own correction, refused for its size); ``slide`` adds the
    sliding search's (:func:`_sliding_starts`, shifts of at least ``slide_beyond_m``), whose
    :data:`VERIFY_SLIDING` cheapest are fitted besides the others' :data:`VERIFY_STARTS`.
    ``align`` is
    :func:`whole_image_alignment`'s, ``ship`` and ``known`` are the whole image's ship and
    labelled pixels."""
    starts = [*_starts(align, silhouette, ship), *extra_starts]
    sliding = _sliding_starts(align, silhouette, slide_beyond_m) if slide else []
    if not starts and not sliding:
        return None
    # the outline's samples are fixed blends of hull points, taken once at the sensors' pose
    # (a silhouette keeps its corners under a shift, a turn or a scale of a nadir view)
    outline = silhouette.outline(align.pixels(silhouette.points_h, np.zeros(4)))
    if outline.shape[1] == 0:
        return None
    scoring = outline[:, ::-(-outline.shape[1] // START_POINTS)]
    # the sliding starts are verified on their own account: at the sensors' scale they
    # would crowd out a blob's start at the right one (a height 40 m off)
    scored, scored_sliding = ([(_start_cost(align, scoring, start), start) for start in group]
                              for group in (starts, sliding))
    if against is not None:         # only starts that fit better than the pose already do
        bar = _start_cost(align, scoring, against)
        scored, scored_sliding = ([item for item in group if item[0] < bar]
                                  for group in (scored, scored_sliding))
    scored.sort(key=lambda item: item[0])
    scored_sliding.sort(key=lambda item: item[0])
    scored = sorted(scored[:VERIFY_STARTS] + scored_sliding[:VERIFY_SLIDING], key=lambda item: item[0])
    window = (slice(0, ship.shape[0]), slice(0, ship.shape[1]))
    height_m = float(align.camera.position_enu[2])
    lowest_m, highest_m = max(MIN_HEIGHT_M, height_m / SCALE_RANGE[1]), height_m / SCALE_RANGE[0]
    best: tuple[tuple[float, float], Placement] | None = None
    for _, start in scored:
        params, _, cost, _ = gauss_newton(align, silhouette, outline, SCHEDULES[1], start,
                                          FLAT_PRIOR_SIGMA ** -2.0, edge_weight)
        if not (math.isfinite(cost) and np.isfinite(params).all()):
            continue
        if not lowest_m <= height_m + params[3] <= highest_m:
            continue            # shrunk to a speck far away, or grown past the scales tried
        final = silhouette.outline(align.pixels(silhouette.points_h, params))
        if final.shape[1] == 0:
            continue
        value = align.residuals(final, params)
        fraction, residual_px, telling = outline_fit(value)
        if telling < MIN_EDGE_POINTS:
            continue
        found = Placement(params, edge_share(value), fraction, residual_px,
                          ship_fill(silhouette.layers_uv(align.pixels(silhouette.points_h, params)), window,
                                    ship, known),
                          len(value) / final.shape[1], telling)
        filled = found.ship_fill >= min_ship_fill
        # among fits good enough to count, the fewest gross errors: a hull shrunk and turned
        # onto another ship's edges fits as cleanly as the own vessel slid 25 m against a
        # neighbour (a camera tilt given wrong at 140 m), and one error is likelier than three
        count = filled and found.edge_share >= count_share
        errors = gross_errors(params) if (count and gross_errors is not None) else 0
        key = (count, -errors, filled, found.edge_share, -cost)
        if best is None or key > best[0]:
            best = (key, found)
        if filled and found.edge_share >= CLEAR_FIT_SHARE and errors <= 1:
            break               # no other start can do much better
    return None if best is None else best[1]
