"""The window of the mask a vessel's outline can reach, and a coarse grid of horizontal
shifts over the sensors' prior.

The pose refinement (:mod:`harborsight.clearance.pose_refinement`) reads the mask within
the prior's reach only (:func:`search_window`). When its first start leaves the outline
short of ship edges, the best cells of a grid of shifts over that reach start more
Gauss-Newton runs (:func:`translation_search`); the sister-hull checks
(:mod:`harborsight.clearance.sister_hulls`) score their starts on the same grid. A cell is
scored by the Tukey cost of the outline's points moved by the shift, to first order in the
shift (:func:`shifted_window_xy`): two projections for the whole grid.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from harborsight.clearance.alignment import MIN_EDGE_POINTS, SCHEDULES, Alignment, tukey_cost
from harborsight.frame import FrameGeometry
from harborsight.vessel.spec import VesselSpec

if TYPE_CHECKING:
    from harborsight.clearance.pose_refinement import PoseRefinementSettings


def prior_reach(settings: PoseRefinementSettings) -> tuple[float, float, float]:
    """The refinement's reach: 2.5 sigma of its prior for the shift (m) and the rotation (deg),
    within the limits, and the height's limit (m)."""
    return (min(settings.max_shift_m, 2.5 * settings.prior_shift_m),
            min(settings.max_rotation_deg, 2.5 * settings.prior_heading_deg),
            settings.max_height_change_m)


def search_window(uv: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec,
                   settings: PoseRefinementSettings, shape: tuple[int, int]
                   ) -> tuple[slice, slice] | None:
    """The part of the image the outline can reach within the search bounds."""
    finite = uv[np.isfinite(uv).all(axis=1)]
    if not len(finite):
        return None
    intr = geometry.camera.intrinsics
    height_m = max(float(geometry.camera.position_enu[2]), 1e-3)
    # 2.5 sigma of the prior: a correction beyond it needs edges the window still holds
    shift_m, rotation_deg, _ = prior_reach(settings)
    reach_m = shift_m + 0.5 * vessel.length_m * math.radians(rotation_deg)
    reach_px = min(reach_m * max(intr.fx, intr.fy) / height_m, max(shape)) + 4
    lo = np.floor(finite.min(axis=0) - reach_px).astype(int)
    hi = np.ceil(finite.max(axis=0) + reach_px).astype(int)
    u0, v0 = max(lo[0], 0), max(lo[1], 0)
    u1, v1 = min(hi[0] + 1, shape[1]), min(hi[1] + 1, shape[0])
    if u1 - u0 < 2 or v1 - v0 < 2:
        return None
    return slice(v0, v1), slice(u0, u1)


#: the coarse translation search's grid step, as a share of the prior's sigma; how many of
#: its best cells start a Gauss-Newton run; at most this many outline points score a cell;
SEARCH_STEP_SIGMA = 1 / 3
SEARCH_STARTS = 2
SEARCH_POINTS = 120
#: the Tukey scale (px) a search cell is scored at: the second schedule's first
SEARCH_TUKEY_PX = SCHEDULES[1][0][1]


def shift_costs(align: Alignment, outline: np.ndarray, params: np.ndarray, de: np.ndarray,
                 dn: np.ndarray, points: int = SEARCH_POINTS) -> np.ndarray | None:
    """The Tukey cost at :data:`SEARCH_TUKEY_PX` of up to ``points`` outline points
    (every k-th) under the correction ``params`` moved by each horizontal shift
    ``(de, dn)`` (metres; points that leave the view count as outliers), one per shift
    (:func:`shifted_window_xy`). None when too few points project."""
    if outline.shape[1] == 0:
        return None
    outline = outline[:, ::-(-outline.shape[1] // points)]    # every k-th point
    shifted = shifted_window_xy(align, outline, params, de, dn)
    if shifted is None or shifted[0].shape[1] < MIN_EDGE_POINTS:
        return None
    xy, seen = shifted
    values = np.full(seen.shape, np.inf)
    values[seen] = align.sdf.sample(xy[seen].T)[0]
    return tukey_cost(values, SEARCH_TUKEY_PX).sum(axis=1)    # |inf| -> the outlier cost


def shifted_window_xy(align: Alignment, outline: np.ndarray, params: np.ndarray,
                       de: np.ndarray, dn: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Window positions ``(shifts, points, 2)`` of the outline's points that project under
    the correction ``params`` moved by each horizontal shift ``(de, dn)`` (metres), and
    which of them are in view and in the window. To first order, ``uv(t) = uv(0) + J t``,
    ``J`` from the projections at 1 m east and 1 m north: one projection per axis instead
    of one per shift. None when no point projects."""
    base = align.pixels(outline, params)
    east = align.pixels(outline, params + np.array([1.0, 0.0, 0.0, 0.0])) - base
    north = align.pixels(outline, params + np.array([0.0, 1.0, 0.0, 0.0])) - base
    keep = np.isfinite(base).all(axis=1) & np.isfinite(east).all(axis=1) & np.isfinite(north).all(axis=1)
    if not keep.any():
        return None
    base, east, north = base[keep], east[keep], north[keep]
    xy = (base[None] + de[:, None, None] * east[None] + dn[:, None, None] * north[None]
          - align.origin.T[None])
    seen = ((xy[..., 0] >= align.lo[0]) & (xy[..., 0] <= align.hi[0])
            & (xy[..., 1] >= align.lo[1]) & (xy[..., 1] <= align.hi[1]))
    return xy, seen


def translation_search(align: Alignment, outline: np.ndarray, settings: PoseRefinementSettings,
                        taken: list[np.ndarray]) -> list[tuple[float, float]]:
    """The best horizontal shifts ``(de, dn)`` (metres) of a grid over the prior's reach
    (within ``min(max_shift_m, 2.5 prior_shift_m)``, steps of :data:`SEARCH_STEP_SIGMA`
    sigma): starts for the Gauss-Newton runs when the sensors are so far off that their
    neighbourhood holds the wrong basin (a start 5 m off with a 3 m prior, docs/results.md).

    A cell is scored by the Tukey cost, at the second schedule's first scale
    (:data:`SEARCH_TUKEY_PX`, the basin its run starts with), of the outline's points
    (:func:`shift_costs`). At most :data:`SEARCH_STARTS` cells, each cheaper than the
    sensors' pose and more than 1.5 steps from the other starts (``taken``, the sensors'
    pose among them) and from each other; none when no cell beats the sensors' pose."""
    reach_m = prior_reach(settings)[0]
    step_m = SEARCH_STEP_SIGMA * settings.prior_shift_m
    n = int(reach_m // step_m)
    if n < 1:
        return []
    offsets = np.arange(-n, n + 1) * step_m
    de, dn = (g.ravel() for g in np.meshgrid(offsets, offsets))
    inside = np.hypot(de, dn) <= reach_m + 1e-9
    de, dn = de[inside], dn[inside]
    cost = shift_costs(align, outline, np.zeros(4), de, dn)
    if cost is None:
        return []
    centre = cost[np.flatnonzero((de == 0) & (dn == 0))[0]]
    found: list[tuple[float, float]] = []
    others = [(float(t[0]), float(t[1])) for t in taken]
    for cell in np.argsort(cost, kind="stable"):
        if cost[cell] >= centre:
            break
        shift = (float(de[cell]), float(dn[cell]))
        if all(math.hypot(shift[0] - e, shift[1] - n_) > 1.5 * step_m for e, n_ in others + found):
            found.append(shift)
            if len(found) == SEARCH_STARTS:
                break
    return found
