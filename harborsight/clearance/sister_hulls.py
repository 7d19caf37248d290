"""Sister hulls: placements of the vessel that fit the mask as well as the one chosen.

Identical vessels moored side by side, in a row or in line fit the mask alike, and the
alignment goes to the one its start lies nearest; a hull the image's border cuts has too
few outline points in view to be scored against a sister in full view. The image cannot
tell such placements apart, so the sensors' prior must (:func:`twin_alongside`,
:func:`cut_hull`); when it cannot either, the refinement keeps the sensors' pose and says
why (:data:`TWIN_ALIKE`, :data:`CUT_ALIKE`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from harborsight.clearance.alignment import (
    DEEP_PX,
    MIN_EDGE_POINTS,
    SCHEDULES,
    Alignment,
    Silhouette,
    gauss_newton,
    homogeneous,
    outline_fit,
    tukey_cost,
)
from harborsight.clearance.gross_errors import beyond, ends_on_edges
from harborsight.clearance.prior_search import (
    SEARCH_STEP_SIGMA,
    SEARCH_TUKEY_PX,
    shift_costs,
    shifted_window_xy,
)
from harborsight.frame import FrameGeometry

if TYPE_CHECKING:
    from harborsight.clearance.pose_refinement import PoseRefinementSettings


#: a pose is checked for a twin alongside when this share of its outline's points in view
#: lies deep inside ship pixels (:data:`~harborsight.clearance.alignment.DEEP_PX`): a side
#: pressed against a neighbour's
TWIN_DEEP_SHARE = 0.2
#: a twin is another placement this share of the hull's beam or more from the pose
TWIN_APART_BEAMS = 0.5
#: placements that fit the mask alike are told apart by the prior alone, and only when their
#: squared prior distances differ by this much (odds of 20 to 1)
TWIN_ODDS_D2 = 2.0 * math.log(20.0)
#: odds said are capped at these (a million to 1): past them the prior decides anyway
MAX_ODDS_D2 = 2.0 * math.log(1e6)
#: how the reason for a pose kept for want of telling twins apart begins
TWIN_ALIKE = "the hull fits the mask as well "
#: another ship blob may hold a twin when its area is within these shares of the hull's
#: silhouette's (both in the window, both eroded and halved alike): less is a buoy, a tender
#: or a twin mostly out of view; more, a larger vessel, inside which the hull would fit with
#: its sides and one end on nothing. Low, for a model's masks: a yacht's blob eroded 2 px
#: at 150 m keeps under half its area
TWIN_BLOB_AREA = (0.4, 1.6)
#: at most this many such blobs are fitted, the likeliest under the prior first
TWIN_BLOB_STARTS = 3
#: a placement on another blob is a sister's when its outline's inlier share is at most
#: this much under the chosen pose's (a 12 m yacht's outline on a 14 m yacht's blob, or on a
#: box's, fits alike by the acceptance tests alone)
TWIN_BLOB_FRACTION = 0.15
#: the same for a candidate the refinement solved before the twin check: one with 0.90 of
#: its outline on edges, 7 m along a hull whose placement had 1.0, was no sister (a bench
#: frame of a marina: the first pass had applied it, and the twin reason left it so)
TWIN_SOLVED_FRACTION = 0.05
#: ... or this many more of its telling points off an edge, where that is more (of 19
#: telling points one off is 0.05: a hull rafted at the border, partly out of view)
TWIN_SOLVED_MISSES = 2
#: a placement on another blob is a sister's only when the ring of pixels just outside its
#: silhouette (:data:`RING_PX`) holds at most this much more ship than the chosen pose's:
#: a 12 x 4 m box's corners lie outside a yacht's outline laid inside it
TWIN_BLOB_RING = 0.1
RING_PX = 1
#: outline points that score a cell on such a blob (every k-th of the outline, so half as
#: many at least: never under the :data:`MIN_EDGE_POINTS` a score needs; at 40, an outline
#: of 41-46 points kept 21-23, and no sister was tried at 80-92 m); a start need only be in
#: the basin of the alignment's first scale
TWIN_BLOB_POINTS = 2 * MIN_EDGE_POINTS


#: a placement fits alike with :data:`MIN_EDGE_POINTS` of its outline's points able to tell
#: (not deep in ship pixels), or this many, half that, when they are at least
#: :data:`ALIKE_MIN_TELLING_SHARE` of its points in view (and :data:`MIN_EDGE_POINTS` are in
#: view): a yacht rafted between two sisters has its sides deep in theirs, and with the 24
#: an alignment needs its true placement (23 telling of about 50 at 100 m) lost to an outer
#: sister, which has a free side (34 of 144 frames laid 4 m over, a reviewer's probe). A
#: tug laid a beam over inside a larger moored ship's blob on a bench frame (a model's
#: mask) kept 20 telling of 102: no sister, and the share tells it apart
ALIKE_MIN_TELLING = MIN_EDGE_POINTS // 2
ALIKE_MIN_TELLING_SHARE = 1.0 / 3.0


def _fits_alike(candidate: tuple, align: Alignment, silhouette: Silhouette,
                settings: PoseRefinementSettings) -> bool:
    """Whether a candidate ``(params, information, cost, signed distances, fill)`` fits the
    mask as a placement of the hull would be accepted: within the limits, the outline's
    points that can tell on edges (:data:`ALIKE_MIN_TELLING`), the silhouette filled, both
    ends on edges where they are not against a neighbour's or out of the picture (a
    sister's stern cut by the image's border, or the vessel's own, does not rule the
    placement out)."""
    params, _, _, value, fill_share = candidate
    if not np.isfinite(params).all() or fill_share < settings.min_ship_fill:
        return False
    if any(beyond(params, settings.max_shift_m, settings.max_rotation_deg,
                   settings.max_height_change_m)):
        return False
    fraction, residual_px, n_edge = outline_fit(value)
    telling = n_edge >= MIN_EDGE_POINTS or (
        n_edge >= ALIKE_MIN_TELLING and n_edge >= ALIKE_MIN_TELLING_SHARE * len(value))
    return (len(value) >= MIN_EDGE_POINTS and telling and fraction >= settings.min_inlier_fraction
            and residual_px is not None and residual_px <= settings.max_residual_px
            and ends_on_edges(align, silhouette, params, against_neighbours=True, unseen_ok=True))


def _drawn_in_window(params: np.ndarray, align: Alignment, silhouette: Silhouette,
                     shape: tuple[int, int]) -> np.ndarray | None:
    """The convex hull of the silhouette's pixels under ``params``, drawn (1) in an array
    of the signed distance's window ``shape``; None when fewer than three points project."""
    uv = align.pixels(silhouette.points_h, params)
    uv = uv[np.isfinite(uv).all(axis=1)]
    if len(uv) < 3:
        return None
    drawn = np.zeros(shape, np.uint8)
    hull = cv2.convexHull(np.round((uv - align.origin.ravel()) * 16).astype(np.int32))
    cv2.fillConvexPoly(drawn, hull, 1, lineType=cv2.LINE_8, shift=4)
    return drawn


def _ring_ship_share(params: np.ndarray, align: Alignment, silhouette: Silhouette,
                     ship: np.ndarray, row: tuple[np.ndarray, ...] = ()) -> float:
    """Share of ship pixels in the ring :data:`RING_PX` wide just outside the silhouette
    under ``params`` (in the signed distance's window ``ship``): water round a hull alone on
    the water, ship where the blob holds more than the hull. With ``row`` (corrections:
    sisters' placements), the lower of that share and the share with the ring pixels
    inside their silhouettes left out: the row can only admit a placement."""
    drawn = _drawn_in_window(params, align, silhouette, ship.shape)
    if drawn is None:
        return 1.0
    size = 2 * RING_PX + 1
    ring = (cv2.dilate(drawn, np.ones((size, size), np.uint8)) > drawn)

    def share() -> float:
        total = np.count_nonzero(ring)
        return float(np.count_nonzero(ring & ship) / total) if total else 1.0

    alone = share()
    if not row:
        return alone
    for other in row:
        sister = _drawn_in_window(other, align, silhouette, ship.shape)
        if sister is not None:
            ring &= sister == 0
    return min(alone, share())


def _row_rings(best: np.ndarray, found: np.ndarray, align: Alignment, silhouette: Silhouette,
               ship: np.ndarray) -> tuple[float, float]:
    """The ring ship shares (:func:`_ring_ship_share`) of the pose ``best`` and of a
    placement ``found`` on a sister's blob, the latter's the lower of its own and its less
    the pixels a row of sisters at their spacing ``d = found - best`` would cover (hulls at
    ``best - d``, ``best`` and ``found + d``): the row can only admit a placement (taken
    out of both rings, it moved the shares apart: 0.032 / 0.113 became 0.009 / 0.122, and a
    real sister 4.8 m abeam was turned away). Sisters moored half a metre apart touch the
    ring along their sides, the middle one's on both: without the row, the true pose
    between two sisters read 0.3 more ship in its ring than an outer sister's, and a 14 m
    yacht in a row was laid a berth over (21 of 108 frames at 95-105 m). A box's corners
    beyond the hull's outline lie under no sister's placement and still count."""
    spacing = found - best
    spacing[2:] = 0.0
    return (_ring_ship_share(best, align, silhouette, ship),
            _ring_ship_share(found, align, silhouette, ship, (best - spacing, best, found + spacing)))


def _shift_d2(params: np.ndarray, prior_diagonal: np.ndarray) -> float:
    """``p^T diag(prior) p`` of a correction's horizontal shift alone: what tells sister
    placements apart. Their turns and heights are one vessel's, fitted twice; a mask's edge
    bias moved the fitted height between them, and with it the odds (2 px of erosion: 25 of
    144 frames of a yacht in a row laid a berth over, 13 on the shift alone)."""
    return float(params[0] ** 2 * prior_diagonal[0] + params[1] ** 2 * prior_diagonal[1])


def _blob_starts(params: np.ndarray, align: Alignment, silhouette: Silhouette, ship: np.ndarray,
                 prior_diagonal: np.ndarray, step_m: float, apart_m: float,
                 max_shift_m: float = math.inf) -> tuple[list[np.ndarray], bool]:
    """Starts of the alignment on the mask's other ship blobs, for identical vessels
    moored apart (a marina's row of charter yachts).

    The blobs are the connected components of the window's ship pixels (``ship``) eroded
    by a 3x3 square and at half the resolution, a pixel ship where all four under it are
    (which parts blobs joined by a pixel or two: a metre of water at 150 m).
    Shifts of the pose ``params`` on a grid of ``step_m`` are kept where the prior cannot
    rule them out (:func:`_shift_d2`, the shift shortened by a step, within
    :data:`TWIN_ODDS_D2` of ``params``'; no farther from the sensors' pose than
    ``max_shift_m``, the most a correction may be: a prior of a kilometre, a receiver
    without a fix, would grid millions of cells at a step of half a beam), ``apart_m`` or
    more from it, and where the hull's centre falls on a blob other than its own whose
    area is within :data:`TWIN_BLOB_AREA` of the silhouette's (drawn in the window and
    parted as the blobs are); per blob the
    cell whose outline fits best (:func:`prior_search.shift_costs`) is a start. At most
    :data:`TWIN_BLOB_STARTS`, the likeliest under the prior first. Blobs clipped by the
    window are so started within a step of their best placement (their centroids are not:
    a hull half out of the window moves it by metres). Also whether the blob under the
    hull's centre is larger than :data:`TWIN_BLOB_AREA` allows a hull alone: sisters whose
    silhouettes lean into one another far from the nadir make one blob (a row of three
    yachts 1 m apart at 100 m, seen 65 m off the nadir: 2.4 hulls' area)."""
    uv = align.pixels(silhouette.points_h, params)
    uv = uv[np.isfinite(uv).all(axis=1)]
    rows, cols = ship.shape[0] // 2 * 2, ship.shape[1] // 2 * 2
    if len(uv) < 3 or min(rows, cols) < 4 or np.count_nonzero(ship) < 1.1 * cv2.contourArea(
            cv2.convexHull(uv.astype(np.float32))):
        return [], False    # too few ship pixels in the window for the hull and a twin

    def parted(mask: np.ndarray) -> np.ndarray:
        # eroded once, and at half the resolution a pixel set only where all four under it
        # are: blobs joined by a pixel or two part, and the labelling costs a quarter
        eroded = cv2.erode(mask, np.ones((3, 3), np.uint8))[:rows, :cols]
        return eroded[::2, ::2] & eroded[1::2, ::2] & eroded[::2, 1::2] & eroded[1::2, 1::2]

    drawn = _drawn_in_window(params, align, silhouette, ship.shape)
    area_px = float(np.count_nonzero(parted(drawn)))      # the hull's, in the window, as a blob's
    least_px, most_px = TWIN_BLOB_AREA[0] * area_px, TWIN_BLOB_AREA[1] * area_px
    if area_px < 1.0:
        return [], False
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(parted(ship.view(np.uint8)), connectivity=8)
    point = homogeneous(np.array([silhouette.points_h[:3].mean(axis=1)]))
    at = align.pixels(point, params)[0] - align.origin.ravel()
    jacobian = np.column_stack([align.pixels(point, params + step)[0] - align.origin.ravel() - at
                                for step in (np.array([1.0, 0, 0, 0]), np.array([0, 1.0, 0, 0]))])
    if not (np.isfinite(at).all() and np.isfinite(jacobian).all()):
        return [], False

    def blob_at(de: np.ndarray, dn: np.ndarray) -> np.ndarray:
        col = np.floor(0.5 * (at[0] + jacobian[0, 0] * de + jacobian[0, 1] * dn)).astype(int)
        row = np.floor(0.5 * (at[1] + jacobian[1, 0] * de + jacobian[1, 1] * dn)).astype(int)
        inside = (row >= 0) & (row < blobs.shape[0]) & (col >= 0) & (col < blobs.shape[1])
        out = np.zeros(len(de), int)
        out[inside] = blobs[row[inside], col[inside]]
        return out

    own = int(blob_at(np.zeros(1), np.zeros(1))[0])
    areas = stats[:, cv2.CC_STAT_AREA]
    merged = own > 0 and areas[own] > most_px
    if count <= 2:
        return [], merged
    d2_best = _shift_d2(params, prior_diagonal)
    reach_m = min(prior_diagonal[0] ** -0.5 * math.sqrt(d2_best + TWIN_ODDS_D2), max_shift_m) + step_m
    n = math.ceil(reach_m / step_m)
    offsets = np.arange(-n, n + 1) * step_m
    east, north = (g.ravel() for g in np.meshgrid(offsets, offsets))      # shifts from the sensors'
    shortened = np.maximum(np.hypot(east, north) - step_m, 0.0)
    de, dn = east - params[0], north - params[1]                          # from the pose
    keep = (shortened ** 2 * prior_diagonal[0] < d2_best + TWIN_ODDS_D2) & (np.hypot(de, dn) >= apart_m)
    de, dn, shortened = de[keep], dn[keep], shortened[keep]
    label = blob_at(de, dn)
    alike = (areas >= least_px) & (areas <= most_px)
    on_other = (label > 0) & (label != own) & alike[label]
    if not on_other.any():
        return [], merged
    de, dn, shortened, label = de[on_other], dn[on_other], shortened[on_other], label[on_other]
    outline = silhouette.outline(align.pixels(silhouette.points_h, params))
    cost = shift_costs(align, outline, params, de, dn, TWIN_BLOB_POINTS)
    if cost is None:
        return [], merged
    starts = []
    for blob in np.unique(label):
        cells = np.flatnonzero(label == blob)
        cell = cells[np.argmin(cost[cells])]
        starts.append((float(shortened[cell]), params + np.array([de[cell], dn[cell], 0.0, 0.0])))
    starts.sort(key=lambda item: item[0])
    return [start for _, start in starts[:TWIN_BLOB_STARTS]], merged


#: the hull at the sensors' pose is cut by the image's border when under this share of its
#: outline's samples are in view
CUT_IN_VIEW = 0.9
#: a hull so cut is aligned from this many outline points in view (half what an alignment
#: needs), to see whether what is in view fits the mask
CUT_MIN_POINTS = MIN_EDGE_POINTS // 2
#: how the reason for a pose kept because the hull where the sensors put it is cut by the
#: image's border, and cannot be told from the alignment's placement, begins
CUT_ALIKE = "the hull where the sensors put it runs out of the picture "


def cut_hull(align: Alignment, silhouette: Silhouette, outline: np.ndarray,
              at_sensors: np.ndarray, params: np.ndarray, prior_diagonal: np.ndarray,
              edge_weight: float, fill, settings: PoseRefinementSettings
              ) -> tuple[tuple, bool, float] | None:
    """The placement of the hull the image's border cuts that joins the sisters' comparison
    (:func:`_cut_at_sensors`: ``(candidate, seen, in_view)``), or None: asked only when
    under :data:`CUT_IN_VIEW` of the outline (``outline``, its signed distances in view at
    the sensors' pose ``at_sensors``) is in view and the chosen correction ``params`` moves
    the hull :data:`TWIN_APART_BEAMS` beams or more. The hull is aligned from the sensors'
    pose on as few as :data:`CUT_MIN_POINTS` points; when that is refused or slides onto
    the chosen placement, again from :func:`_cut_starts` with the height held at the
    sensors' (a cut outline hardly measures the scale: a reviewer found the fit from the
    sensors' pose refused in 3 of 4 frames still laid on a sister, its silhouette on water
    or its height 4-8 m off, where a fit from the truth passed). When none fills the
    silhouette as an accepted placement must, the first that fills :data:`CUT_FILL_SHARE`
    of it joins."""
    in_view = len(at_sensors) / outline.shape[1]
    apart_m = TWIN_APART_BEAMS * float(np.ptp(silhouette.points_h[1]))
    if in_view >= CUT_IN_VIEW or math.hypot(*params[:2]) < apart_m:
        return None

    relaxed = align.with_min_points(CUT_MIN_POINTS)
    held = prior_diagonal.copy()
    held[3] = CUT_HELD_HEIGHT_M ** -2.0

    def alignments():
        first = gauss_newton(relaxed, silhouette, outline, SCHEDULES[1], np.zeros(4),
                             prior_diagonal, edge_weight)
        yield first
        for start in _cut_starts(relaxed, outline, params, prior_diagonal, apart_m, first[0]):
            yield gauss_newton(relaxed, silhouette, outline, SCHEDULES[1], start, held, edge_weight)

    # (a fit on the chosen placement never joins; the unseen sensors' pose comes only from
    # the first, which fails whenever under CUT_MIN_POINTS points are in view)
    short = None        # the first fit that fills only CUT_FILL_SHARE of what it must
    for solved in alignments():
        cut = _cut_at_sensors(solved, at_sensors, in_view, fill, settings)
        if cut is None or (cut[1] and math.hypot(*(cut[0][0][:2] - params[:2])) < apart_m):
            continue
        if not cut[1] or cut[0][4] >= settings.min_ship_fill:
            return cut
        short = short or cut
    return short


#: the share of an accepted placement's fill (``min_ship_fill``) a cut hull's placement
#: needs when none has that: aligned on so few points it lies up to a metre off along a
#: hull whose end is out of the picture, an end over water (fills of 0.72-0.87 were found
#: 0.4-0.9 m from the truth, where the sister beside it was laid on)
CUT_FILL_SHARE = 0.8
#: the height's prior (m) while a cut hull is aligned from a grid cell: held at the sensors'
CUT_HELD_HEIGHT_M = 1e-6
#: cells of the grid over the prior's reach that start such alignments
CUT_STARTS = 2


def _cut_starts(align: Alignment, outline: np.ndarray, params: np.ndarray,
                prior_diagonal: np.ndarray, apart_m: float, fitted: np.ndarray | None = None
                ) -> list[np.ndarray]:
    """Starts, ``apart_m`` or more from the chosen correction ``params``, for a cut hull's
    alignment with its height held: where the alignment from the sensors' pose ``fitted``
    it, at the sensors' height (a tilted camera's cut hull was fitted 0.4 m from the truth
    with its height 5 m off, beyond the limit); then the :data:`CUT_STARTS` cells of a grid
    over the prior's reach (2.5 sigma, steps of :data:`prior_search.SEARCH_STEP_SIGMA`
    sigma) whose outline points in view (at least :data:`CUT_MIN_POINTS`) have the least
    mean Tukey cost at :data:`prior_search.SEARCH_TUKEY_PX`, the nearer the sensors' pose
    first among equals. A mean, not :func:`prior_search.shift_costs`' sum with points out
    of view as outliers, which ranks every cut placement below one in full view
    (:func:`prior_search.shifted_window_xy`)."""
    starts = []
    if (fitted is not None and np.isfinite(fitted).all()
            and math.hypot(*(fitted[:2] - params[:2])) >= apart_m):
        starts.append(np.array([*fitted[:3], 0.0]))
    sigma_m = prior_diagonal[0] ** -0.5
    step_m = SEARCH_STEP_SIGMA * sigma_m
    n = int(2.5 * sigma_m // step_m)
    if n < 1 or outline.shape[1] == 0:
        return starts
    offsets = np.arange(-n, n + 1) * step_m
    de, dn = (g.ravel() for g in np.meshgrid(offsets, offsets))
    keep = (np.hypot(de, dn) <= 2.5 * sigma_m + 1e-9) & (np.hypot(de - params[0], dn - params[1]) >= apart_m)
    de, dn = de[keep], dn[keep]
    shifted = shifted_window_xy(align, outline, np.zeros(4), de, dn) if len(de) else None
    if shifted is None:
        return starts
    xy, seen = shifted
    cost = np.zeros(seen.shape)
    cost[seen] = tukey_cost(align.sdf.sample(xy[seen].T)[0], SEARCH_TUKEY_PX)
    count = seen.sum(axis=1)
    mean = np.where(count >= CUT_MIN_POINTS, cost.sum(axis=1) / np.maximum(count, 1), np.inf)
    order = np.argsort(mean + 1e-3 * (de ** 2 + dn ** 2), kind="stable")
    return starts + [np.array([de[c], dn[c], 0.0, 0.0]) for c in order[:CUT_STARTS] if np.isfinite(mean[c])]


def _cut_at_sensors(solved: tuple, at_sensors: np.ndarray, in_view: float, fill,
                    settings: PoseRefinementSettings) -> tuple[tuple, bool, float] | None:
    """The placement of a hull the image's border cuts, near the sensors' pose, that the
    image cannot refute, whether any of it is seen, and ``in_view``: ``(candidate, seen,
    in_view)``, or None.

    ``solved`` is an alignment (:func:`gauss_newton`'s ``(params, information, cost,
    signed distances)``) on as few as :data:`CUT_MIN_POINTS` outline points in view;
    ``at_sensors`` the outline's signed distances in view at the sensors' pose,
    ``in_view`` their share of the outline. When that alignment fits what is in view as a
    placement would be accepted (inliers, residual, the silhouette's pixels in view ship,
    of these :data:`CUT_FILL_SHARE` of ``min_ship_fill`` at least), it is the placement,
    seen. When fewer
    than :data:`CUT_MIN_POINTS` points are in view at the sensors' pose, the image says
    nothing of the hull there: the sensors' pose itself, unseen. Otherwise what is in view
    is not this hull's edges: None."""
    params, information, cost, value = solved
    if np.isfinite(cost) and np.isfinite(params).all():
        fraction, residual_px, telling = outline_fit(value)
        filled = fill(params)
        if (telling >= CUT_MIN_POINTS and fraction >= settings.min_inlier_fraction
                and residual_px is not None and residual_px <= settings.max_residual_px
                and filled >= CUT_FILL_SHARE * settings.min_ship_fill
                and not any(beyond(params, settings.max_shift_m, settings.max_rotation_deg,
                                    settings.max_height_change_m))):
            return (params, information, cost, value, filled), True, in_view
        return None
    if len(at_sensors) < CUT_MIN_POINTS and in_view < CUT_IN_VIEW:
        return (np.zeros(4), None, np.inf, at_sensors, fill(np.zeros(4))), False, in_view
    return None


#: a cut placement is another vessel's only when at most this share of its silhouette lies
#: under the chosen pose's
CUT_OVERLAP = 0.25


def _cut_alike(cut: np.ndarray, seen: bool, params: np.ndarray, align: Alignment,
               silhouette: Silhouette, shape: tuple[int, int]) -> bool:
    """Whether the placement ``cut`` of a hull the image's border cuts may be the vessel's
    as the chosen pose ``params`` may: at most :data:`CUT_OVERLAP` of its silhouette under
    the chosen pose's (sisters lie side by side or in line, apart), and, when part of it is
    ``seen``, its ends in view on edges. Laid from the sensors' pose onto a larger ship the
    vessel touches (a tug 6 m off at 40 m), the relaxed alignment fitted what was in view
    with an end on nothing; on a bench frame it slid the tug 7 m along its own image, an end
    out of the picture. The ring test of sisters' blobs (:func:`_row_rings`) is not asked: a
    placement from so few points lies up to 2 m off, and its ring catches the vessel's own
    pixels (0.2-0.4 of it, against a sister's 0.01-0.03)."""
    if seen and not ends_on_edges(align, silhouette, cut, against_neighbours=True, unseen_ok=True):
        return False
    drawn = _drawn_in_window(cut, align, silhouette, shape)
    chosen = _drawn_in_window(params, align, silhouette, shape)
    area = 0 if drawn is None else np.count_nonzero(drawn)
    if area == 0 or chosen is None:     # (a hull wholly out of the window overlaps nothing)
        return area > 0 or not seen
    return np.count_nonzero(drawn & chosen) <= CUT_OVERLAP * area


def twin_alongside(best: tuple, align: Alignment, silhouette: Silhouette, geometry: FrameGeometry,
                    settings: PoseRefinementSettings, prior_diagonal: np.ndarray, solve, fill,
                    ship: np.ndarray, cut: tuple[tuple, bool, float] | None = None,
                    solved: list[tuple] = ()) -> tuple[tuple, str | None]:
    """The placement to keep when the hull may be one of identical vessels moored side by
    side or in a row, and why none can be kept when the sensors cannot tell which.

    A vessel moored between two sister hulls, touching, makes one ship blob three beams
    wide whose every beam-wide strip holds a hull with its bow and stern on edges. The
    alignment's cost counts the outline's points deep inside ship pixels as misses, so a
    placement on an outer twin (one side on the blob's edge) beats the true one (both sides
    against the twins'): on schematic rafts at the documented sensor errors, 41 of 96 frames
    were laid one beam over and applied. Identical vessels moored apart (a marina's row of
    yachts 5 m apart) are separate blobs that fit alike, and the alignment goes to the one
    its start lies nearest: 19 of 96 frames of a 12 m yacht in a row of five were laid a
    berth over at the documented errors. The image cannot tell such placements apart, so
    the prior must. When ``best`` (a candidate ``(params, information, cost, signed
    distances, fill)``) has :data:`TWIN_DEEP_SHARE` of its outline deep in ship pixels, the
    alignment is run again from a beam to either side where the silhouette there is filled
    (``fill(params)`` its share of ship pixels; ``solve(start)`` returns a candidate); and
    from the other blobs of the hull's size the prior cannot rule out
    (:func:`_blob_starts`); the candidates the refinement ``solved`` already (from the
    sensors' pose and a beam to either side) are checked as those from blobs are, with no
    solve (a hull partly out of the picture, fitted 5 m off its sister from a start a beam
    over, lost to the sister on cost, its points out of view counted as misses, and was
    never compared). Of ``best`` and the placements that fit as one would be
    accepted (:func:`_fits_alike`), all :data:`TWIN_APART_BEAMS` beams or more apart, the
    one nearest the sensors' pose under the prior (of the shifts alone, :func:`_shift_d2`)
    is kept, when it is nearer than the next by :data:`TWIN_ODDS_D2`; otherwise the reason to keep the
    sensors' pose is returned with it.

    A hull the image's border cuts at the sensors' pose (``cut``, :func:`_cut_at_sensors`)
    has too few outline points in view to be scored against a sister in full view, which
    then wins on cost alone: a yacht in a row seen from 75 m to one side was laid a berth
    over on 35 of 144 frames, most of them with its own hull partly out of view. That
    placement joins the comparison; when it is the likelier, or the odds cannot tell, the
    sensors' pose is kept."""
    params, value = best[0], best[3]
    if not len(value):
        return best, None
    beam_m = float(np.ptp(silhouette.points_h[1]))
    heading = geometry.vessel_heading_rad + float(params[2])
    across = np.array([math.cos(heading), -math.sin(heading)])      # starboard, in ENU
    bow = np.array([math.sin(heading), math.cos(heading)])
    # (a step under half a beam lands on every sister's blob, however wide the prior)
    on_blobs, merged = _blob_starts(params, align, silhouette, ship, prior_diagonal,
                                    min(SEARCH_STEP_SIGMA * prior_diagonal[0] ** -0.5, 0.5 * beam_m),
                                    TWIN_APART_BEAMS * beam_m, settings.max_shift_m)
    # (start, or candidate already solved; whence: "solved", "beside" (not compared with
    # the chosen pose's fit) or "blob"; every one's ring is)
    starts = [(c, "solved") for c in solved if c is not best]
    if merged or np.count_nonzero(value < -DEEP_PX) >= TWIN_DEEP_SHARE * len(value):
        for side in (1.0, -1.0):
            start = params + side * beam_m * np.array([*across, 0.0, 0.0])
            if fill(start) >= settings.min_ship_fill:   # else water or a quay: no twin (a solve ~2 ms)
                starts.append((start, "beside"))
    starts += [(start, "blob") for start in on_blobs]
    best_fraction = None        # reckoned once, when a placement asks
    alike = [best]
    for start, whence in starts:
        found = start if isinstance(start, tuple) else solve(start)
        if not (all(math.hypot(*(found[0][:2] - c[0][:2])) >= TWIN_APART_BEAMS * beam_m for c in alike)
                and _fits_alike(found, align, silhouette, settings)):
            continue
        if whence != "beside":
            if best_fraction is None:
                best_fraction = outline_fit(value)[0]
            fraction, _, telling = outline_fit(found[3])
            below = (TWIN_BLOB_FRACTION if whence == "blob"
                     else max(TWIN_SOLVED_FRACTION, TWIN_SOLVED_MISSES / telling))
            if fraction < best_fraction - below:
                continue
        best_ring, found_ring = _row_rings(params, found[0], align, silhouette, ship)
        if found_ring > best_ring + TWIN_BLOB_RING:
            continue            # ship beyond its outline: a larger vessel of another shape
        alike.append(found)
    cut_at = None       # the index of the cut placement in ``alike``
    if cut is not None and all(math.hypot(*(cut[0][0][:2] - c[0][:2])) >= TWIN_APART_BEAMS * beam_m
                               for c in alike) and _cut_alike(cut[0][0], cut[1], params, align,
                                                              silhouette, ship.shape):
        alike.append(cut[0])
        cut_at = len(alike) - 1
    if len(alike) == 1:
        return best, None
    d2 = [_shift_d2(c[0], prior_diagonal) for c in alike]
    first, second = np.argsort(d2, kind="stable")[:2]
    # (capped: a prior of 2 cm and a sister 10 m off are odds of e^125000, past a float)
    odds = math.exp(min(0.5 * (d2[second] - d2[first]), 0.5 * MAX_ODDS_D2))
    offset_m = alike[second][0][:2] - alike[first][0][:2]
    if cut_at in (first, second):
        if first != cut_at and d2[second] - d2[first] >= TWIN_ODDS_D2:
            return alike[first], None
        said = (f"{100 * cut[2]:.0f} % of its outline in view"
                + (", fitting the mask there" if cut[1] else ""))
        apart_m = math.hypot(*offset_m)
        if first == cut_at and d2[second] - d2[first] >= TWIN_ODDS_D2:
            return best, (f"{CUT_ALIKE}({said}); a placement {apart_m:.1f} m from there fits the "
                          f"mask in full, but the sensors' pose favours the hull where they put it "
                          f"{f'{odds:.0f}' if odds < 1e6 else 'more than a million'} to 1")
        return best, (f"{CUT_ALIKE}({said}), and a placement {apart_m:.1f} m from there fits the "
                      f"mask as well: the sensors' pose tells them apart only {odds:.1f} to 1 "
                      f"(at least {math.exp(0.5 * TWIN_ODDS_D2):.0f} to 1 needed)")
    if d2[second] - d2[first] >= TWIN_ODDS_D2:
        return alike[first], None
    abeam = abs(float(offset_m @ across)) >= abs(float(offset_m @ bow))
    where = "abeam (a vessel alike alongside)" if abeam else "ahead or astern (a vessel alike in line)"
    return alike[first], (f"{TWIN_ALIKE}{math.hypot(*offset_m):.1f} m {where}, and the "
                      f"sensors' pose tells them apart only {odds:.1f} to 1 "
                      f"(at least {math.exp(0.5 * TWIN_ODDS_D2):.0f} to 1 needed)")
