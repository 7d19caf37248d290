"""The shift along a hull whose ends are out of view: held at the sensors' value.

Along a straight run of hull the silhouette's sides slide into themselves: with neither
end of the hull in the picture, the image does not measure where the vessel lies along its
own length. The signed distance still has gradients along the hull there (a pixel
staircase's, a neighbour's notch that pulls outline points deep inside ship pixels), and
Gauss-Newton followed them: a 180 m ship seen 39 % in view slid 10 m along itself from
sensors 1.2 m off, and 8 m from the exact pose, applied and unflagged, with its sections'
bands read off other stretches of quay (docs/results.md, "A long ship with no end in
view"). So when neither end shows, the alignment holds that component of its correction at
the sensors' value (:func:`~harborsight.clearance.alignment.gauss_newton`'s ``held``), and
the sensors' error in it stays in the bars: in each distance read along a direction ``d``,
``(d·a)² (σ_uav² + σ_vessel²)`` per axis, ``a`` the hull's direction on the water
(:func:`along_variance_m2`), and in which band an obstacle near a boundary falls
(:mod:`~harborsight.clearance.band_margin`).

An end is seen when at least :data:`~harborsight.clearance.gross_errors.ENDS_MIN_POINTS`
of the outline's points within :data:`END_REACH_BEAMS` of a beam of the bow's or the
stern's tip are in view, at the sensors' pose or at the correction the alignment found
(sensors 3 m off along a 32 m tug seen from 30 m put its bow just outside the picture; the
alignment found it inside). The reach is short on purpose: the sides near
an end run along the hull and tell no more than the rest of them. Where the end's points lie
(on an edge, or deep inside ship pixels) is not asked: a sensors' pose 2 m astern puts a
bow in view deep inside the hull's own pixels, and the alignment finds it from there.
"""

from __future__ import annotations

import math

import numpy as np

from harborsight.clearance.alignment import Alignment, Silhouette
from harborsight.clearance.gross_errors import ENDS_MIN_POINTS
from harborsight.geometry.sensor_sigmas import SensorSigmas

#: an end's outline points lie within this share of the hull's beam of its tip (the
#: transom's line, a bow's point and the start of its taper)
END_REACH_BEAMS = 0.25


def an_end_seen(align: Alignment, silhouette: Silhouette, params: np.ndarray) -> bool:
    """Whether the bow or the stern of the silhouette's outline shows in the image under the
    correction ``params`` (module docstring)."""
    outline = silhouette.outline(align.pixels(silhouette.points_h, params))
    x = silhouette.points_h[0]
    reach = END_REACH_BEAMS * float(np.ptp(silhouette.points_h[1]))
    for end in (outline[:, outline[0] >= x.max() - reach], outline[:, outline[0] <= x.min() + reach]):
        if end.shape[1] == 0:
            continue
        if len(align.residuals(end, params)) >= ENDS_MIN_POINTS:
            return True
    return False


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
