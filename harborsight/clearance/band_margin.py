"""Obstacles beside a band that a pose the image did not confirm may put inside it.

An obstacle point belongs to the section whose band holds it: the section with its nearest
hull point, the hull placed by the pose. When the image neither moved the hull nor found
the sensors' pose fitting (the alignment refused, or was off), that pose carries the
sensors' full errors, metres and degrees, and a point given to a neighbouring band near the
boundary ray they share may lie in this band in truth. The sections' sigmas speak for the
obstacle each one found, not for one its neighbour took: a pile 2.5 m off a tug's quarter,
read as its neighbour's, left its own band "clear to 32.5 m" (docs/results.md, "Silent wrong
distances on imperfect masks").

For an obstacle point ``P`` of band ``j`` beside the ray ``B + s r`` (unit ``r``, unit normal
``n``, ``s >= 0``) between bands ``j`` and ``k``, its offset across the ray ``e = n·(P - B)``
moves, to first order, by ``n·δ_s`` under a one-sigma error of each independent source ``s``,
``δ_s`` the motion of ``P`` relative to the hull:

* the drone's and the vessel's horizontal position, per axis: the shift itself (the two axes
  together add ``σ²`` whatever ``n``);
* the vessel's heading: the hull turns about the antenna ``V``, and ``P`` moves against it
  by ``σ_ψ perp(P - V)``;
* the camera's height (with the focal length's scale), yaw and tilt: where ``P``'s pixel
  meets the water with the camera moved by one sigma, minus where it meets it now;
* the clock, where the frame gives both ground velocities: ``σ_t (v_uav - v_vessel)``.

``σ_e² = Σ_s (n·δ_s)²``. Where ``|e| <= z σ_e`` (``z`` the lower bound's one-sided 95 %,
:data:`~harborsight.clearance.uncertainty.LOWER_BOUND_Z`), ``P`` lies in band ``k`` with at
least that bound's chance, at about ``s = r·(P - B)`` from band ``k``'s hull: ``B`` is the
nearest hull point of every point on the ray, so the hull runs across the ray there, and
``P`` moves along it (``|P - B|``, used first, left a quay 0.4 m under a bound where ``P``
lay 3 m beside the ray). So a ``clear`` band's ``clear_to_m`` and an ``ok`` band's
``distance_lower_m`` are at most the least such ``s``: nothing solid is known to be absent
nearer. A hull placed by the image, or a pose the image confirmed, moves by
centimetres, and the bands stay as they are; except along a hull with no edge across its
length in view, whose place along it the alignment held at the sensors' (:mod:`.along_hull`): there
only that term remains, ``σ_e = |n·a| sqrt(σ_uav² + σ_vessel²)`` per axis, ``a`` the hull's
direction (:func:`~harborsight.clearance.along_hull.along_variance_m2`).
"""

from __future__ import annotations

import math

import numpy as np

from harborsight.clearance.along_hull import along_variance_m2
from harborsight.clearance.pose_refinement import PoseRefinement
from harborsight.clearance.report import STATUS_CLEAR, STATUS_OK, SectionClearance
from harborsight.clearance.uncertainty import (
    LOWER_BOUND_Z,
    FrameVelocities,
    image_confirms_sensors,
    perturbed_plane_points,
)
from harborsight.frame import FrameGeometry
from harborsight.geometry.sensor_sigmas import SensorSigmas
from harborsight.vessel.sections import SectionedOutline


def pose_kept_unconfirmed(refinement: PoseRefinement) -> bool:
    """Whether the hull lies where the sensors put it, unchecked by the image: the
    alignment neither moved it nor found the sensors' pose fitting (or did not run)."""
    return not (refinement.applied or image_confirms_sensors(refinement))


def offset_sigma_m(geometry: FrameGeometry, sigmas: SensorSigmas, points_px: np.ndarray,
                   normal_enu: np.ndarray, velocities: FrameVelocities | None = None
                   ) -> np.ndarray:
    """One sigma (m) of each point's offset across its boundary ray, ``(N,)``, from the
    pixels ``points_px (N, 2)`` of points on the water and the rays' unit normals on the
    water ``normal_enu (N, 2)``, under the sensors' errors (module docstring). NaN where a
    perturbed camera's ray misses the water (the point is then not capped by this)."""
    camera = geometry.camera
    planes = perturbed_plane_points(camera, sigmas, points_px)          # (1 + C, N, 2)
    here = planes[0]
    variance = np.full(len(points_px), sigmas.uav_axis_m ** 2 + sigmas.vessel_axis_m ** 2)
    for moved in planes[1:]:
        variance += np.einsum("ij,ij->i", normal_enu, moved - here) ** 2
    arm = here - geometry.vessel_position_enu[:2]
    turn = math.radians(sigmas.vessel_heading_deg) * np.column_stack((arm[:, 1], -arm[:, 0]))
    variance += np.einsum("ij,ij->i", normal_enu, turn) ** 2
    if (velocities is not None and velocities.uav_en_mps is not None
            and velocities.vessel_en_mps is not None):
        relative = np.subtract(velocities.uav_en_mps, velocities.vessel_en_mps)
        variance += (sigmas.clock_s * (normal_enu @ relative)) ** 2
    return np.sqrt(variance)


def cap_by_neighbours_margins(
    results: list[SectionClearance], outline_v: SectionedOutline, points_v: np.ndarray,
    points_px: np.ndarray, section: np.ndarray, geometry: FrameGeometry,
    refinement: PoseRefinement, sigmas: SensorSigmas,
    velocities: FrameVelocities | None = None,
) -> None:
    """Cap each ``clear`` section's ``clear_to_m`` and each ``ok`` section's
    ``distance_lower_m`` (in place) by the obstacle points of its two neighbours that the
    pose, unconfirmed by the image, may put in its band (module docstring).

    ``outline_v``: the sections in the vessel frame; ``points_v (N, 2)`` the obstacles'
    contour points there, ``points_px`` their pixels and ``section`` their bands (-1: none).
    Nothing changes when the image placed the hull or confirmed the sensors' pose, but for
    its place along a hull with no edge across its length in view
    (``refinement.along_hull_held``)."""
    n = outline_v.n_sections
    kept = pose_kept_unconfirmed(refinement)
    if n < 2 or len(points_v) == 0 or not (kept or refinement.along_hull_held):
        return
    cap_m = np.full(n, np.inf)
    for result in results:
        if result.status == STATUS_CLEAR:
            cap_m[result.index] = np.inf if result.clear_to_m is None else result.clear_to_m
        elif result.status == STATUS_OK and result.distance_lower_m is not None:
            cap_m[result.index] = result.distance_lower_m
        else:
            cap_m[result.index] = -np.inf         # out of view, or no bound: nothing to cap
    # (point, break) pairs: a point of band j beside the break it shares with band k = j ± 1,
    # in front of the hull and nearer to the break than band k's present cap
    rows, breaks, targets = [], [], []
    valid = np.flatnonzero(section >= 0)
    j = section[valid]
    # band j + 1 starts at break j + 1; band j - 1 ends at break j
    for k, b in (((j + 1) % n, (j + 1) % n), ((j - 1) % n, j)):
        from_break = points_v[valid] - outline_v.break_points[b]
        along = np.einsum("ij,ij->i", from_break, outline_v.break_ray[b])
        keep = (along >= 0) & (along < cap_m[k])
        rows.append(valid[keep])
        breaks.append(b[keep])
        targets.append(k[keep])
    rows, breaks, targets = (np.concatenate(a) for a in (rows, breaks, targets))
    if len(rows) == 0:
        return
    relative = points_v[rows] - outline_v.break_points[breaks]
    ray = outline_v.break_ray[breaks]
    offset_m = np.abs(relative[:, 0] * ray[:, 1] - relative[:, 1] * ray[:, 0])
    # the ray's normal on the water: the vessel frame's direction turned into ENU
    origin_enu = geometry.vessel_to_enu(np.zeros((1, 2)))[0, :2]
    normal_enu = geometry.vessel_to_enu(np.column_stack((-ray[:, 1], ray[:, 0])))[:, :2] - origin_enu
    if kept:
        sigma_m = offset_sigma_m(geometry, sigmas, points_px[rows], normal_enu, velocities)
    else:
        sigma_m = np.sqrt(along_variance_m2(normal_enu, geometry.vessel_heading_rad, sigmas))
    inside = np.flatnonzero(offset_m <= LOWER_BOUND_Z * np.nan_to_num(sigma_m))
    if len(inside) == 0:
        return
    reach = np.einsum("ij,ij->i", relative[inside], ray[inside])
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, targets[inside], reach)
    for result in results:
        k = result.index
        if not nearest[k] < cap_m[k]:
            continue
        if result.status == STATUS_CLEAR:
            result.clear_to_m = float(nearest[k])
        else:
            result.distance_lower_m = float(nearest[k])
