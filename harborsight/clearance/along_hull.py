"""The shift along a hull the image cannot place along its length: held at the sensors' value.

Along a straight run of hull the silhouette's sides slide into themselves: with neither
end of the hull in the picture, the image does not measure where the vessel lies along its
own length. The signed distance still has gradients along the hull there (a pixel
staircase's, a neighbour's notch that pulls outline points deep inside ship pixels), and
Gauss-Newton followed them: a 180 m ship seen 39 % in view slid 10 m along itself from
sensors 1.2 m off, and 8 m from the exact pose, applied and unflagged, with its sections'
bands read off other stretches of quay (docs/results.md, "A long ship with no edge across
its length in view"). So when no edge in view tells (below), the alignment holds that
component of its correction at the sensors' value
(:func:`~harborsight.clearance.alignment.gauss_newton`'s ``held``), and the sensors' error
in it stays in the bars: in each distance read along a direction ``d``,
``(d·a)² (σ_uav² + σ_vessel²)`` per axis, ``a`` the hull's direction on the water
(:func:`along_variance_m2`), and in which band an obstacle near a boundary falls
(:mod:`~harborsight.clearance.band_margin`).

The image places the hull along its length where the outline in view has edges that cross
the direction in which such a slide moves them in the image: the transom, a bow's taper, a
deckhouse's face standing out of the hull's image. An outline sample lies on such an edge
when the step to the next sample, in the image, turns :data:`ACROSS_MIN_DEG` or more from
where a metre along the hull moves it (a parallel midbody's sides do not; nor, often, the
vertical edge of a deckhouse seen obliquely, whose image runs along the hull's side). At
least :data:`~harborsight.clearance.gross_errors.ENDS_MIN_POINTS` of them must be in view and
not deep inside ship pixels at the sensors' pose (:data:`~harborsight.clearance.alignment.
DEEP_PX`: an edge inside a touching neighbour's pixels cannot tell), or on a ship edge at the
correction the alignment found (sensors 3 m off along a 32 m tug seen from 30 m put its bow
deep inside the hull's own pixels; the alignment found it on its edge; a 184 m ship slid
10 m brought its deckhouse's aft edge into the picture, inside the ship's pixels).
"""

from __future__ import annotations

import math

import numpy as np

from harborsight.clearance.alignment import DEEP_PX, INLIER_PX, SAMPLE_STEP_PX, Alignment, Silhouette
from harborsight.clearance.gross_errors import ENDS_MIN_POINTS
from harborsight.geometry.sensor_sigmas import SensorSigmas

#: an edge whose image turns this far or more from a slide's motion tells where the hull lies
ACROSS_MIN_DEG = 20.0


def sees_along(align: Alignment, silhouette: Silhouette, params: np.ndarray,
               on_edges: bool = False) -> bool:
    """Whether the silhouette's outline under the correction ``params`` has edges in view
    that a slide along the hull moves across themselves (module docstring): not deep inside
    ship pixels, or with ``on_edges`` most of those within :data:`~harborsight.clearance.
    alignment.INLIER_PX` of a ship edge (a correction found must have put them there; the
    vertical edge of a deckhouse crossing a ship's edge has a few points near it)."""
    outline = silhouette.outline(align.pixels(silhouette.points_h, params))
    if outline.shape[1] < 2:
        return False
    here = align.pixels(outline, params)
    slid = outline.copy()
    slid[0] += 1.0                          # a metre toward the bow, in the vessel frame
    motion = (align.pixels(slid, params) - here)[:-1]
    # (steps between samples apart, across a layer's junction or a covered stretch, are no
    # edge's direction)
    tangent = np.diff(here, axis=0)
    step_px = np.hypot(*tangent.T)
    cross = np.abs(tangent[:, 0] * motion[:, 1] - tangent[:, 1] * motion[:, 0])
    norms = step_px * np.hypot(*motion.T)
    with np.errstate(invalid="ignore"):
        across = ((cross >= math.sin(math.radians(ACROSS_MIN_DEG)) * norms) & (norms > 0)
                  & (step_px <= 2.0 * SAMPLE_STEP_PX))
    values = align.residuals(outline[:, :-1][:, across], params)
    telling = np.count_nonzero(values > -DEEP_PX)
    if not on_edges:
        return telling >= ENDS_MIN_POINTS
    # most of them on edges: an edge that only crosses a ship's edge has a few points near it
    fitting = np.count_nonzero(np.abs(values) <= INLIER_PX)
    return fitting >= max(ENDS_MIN_POINTS, 0.5 * telling)


def along_direction(heading_rad: float) -> np.ndarray:
    """The correction's unit direction ``(de, dn, dpsi, dh)`` that slides the vessel along
    its own length, heading ``heading_rad`` (clockwise from north)."""
    return np.array([math.sin(heading_rad), math.cos(heading_rad), 0.0, 0.0])


def along_variance_m2(directions: np.ndarray, heading_rad: float, sigmas: SensorSigmas) -> np.ndarray:
    """The sensors' variance (m²) of the distances read along ``directions (N, 2)`` (ENU)
    from a hull whose position along its length is theirs: ``(d·a)²`` times the two
    receivers' per-axis variances."""
    axis = along_direction(heading_rad)[:2]
    return (directions @ axis) ** 2 * (sigmas.uav_axis_m ** 2 + sigmas.vessel_axis_m ** 2)
