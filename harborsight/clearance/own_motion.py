"""The vessel's own motion of each clearance: how fast its velocity and turn change a
section's gap, were the obstacle fixed.

A section's clearance runs from its hull point ``h`` to its obstacle point ``o`` (ENU, metres),
``n = (o - h) / |o - h|``. The hull point moves with the vessel's ground velocity ``v`` (its
GNSS receiver's, at the antenna ``c``) and turns with the vessel's rate of turn ``ψ̇`` (the
heading's: clockwise, rad/s) about the antenna, ``v_h = v + ψ̇ (r_n, -r_e)`` with
``r = h - c``. Were the obstacle fixed, the clearance changes at

    ḋ_own = -v_h · n,
    σ² = σ_v² + ((r_n n_e - r_e n_n) σ_ψ̇)² + (ℓ ψ̇)² + (ℓ σ_ψ̇)² + ((v_h · t) σ_θ)²

``σ_v`` the velocity's sigma per axis (the same on every axis, so its part along ``n`` is
``σ_v``), ``σ_ψ̇`` the turn's. Two more terms cover where the points are not known:

* where a straight stretch of hull runs parallel to the obstacle, any of its points is
  nearest, and a turn closes the gap at one end of it while opening it at the other:
  ``ℓ`` is half the section's length (its chord), so ``ℓ ψ̇`` bounds what the choice of
  point changes;
* the obstacle point is a pixel of an edge, and along a straight edge its place is loose by
  about a pixel, which tilts ``n`` by ``σ_θ = gsd / |o - h|`` (at most 1 rad): a vessel moving
  along the quay at ``v_h · t`` (``t`` across ``n``) then reads a rate it does not have.

The tracker (:mod:`harborsight.flight.tracking`) takes ``ḋ_own`` as the vessel's part of
each distance's rate; what the readings show beyond it is the obstacle's own motion (a boat
under way), so a quay's closing speed follows the vessel's own speed at once, a stop
included, and a moving boat's is still measured.

Sigmas: the frame's own (``vessel.velocity_sigma_mps``, ``vessel.yaw_rate_sigma_deg_s``),
else :data:`VELOCITY_SIGMA_MPS` for a velocity (a receiver's Doppler speed: 0.05 m/s is a
consumer module's datasheet figure, an NMEA or AIS speed is given to 0.1 kn),
:data:`YAW_RATE_SIGMA_DEG_S` for a rate of turn and, for a frame without one, the vessel
taken as not turning within :data:`UNMEASURED_TURN_DEG_S`: at 15 m from the antenna that is
0.13 m/s. Telemetry logs give the velocity from the speed and course over ground (NMEA RMC,
AIS) and the rate of turn from NMEA ROT or AIS, else fitted to their headings
(:func:`harborsight.telemetry.metadata.own_motion_fields`, :meth:`Track.heading_rate
<harborsight.telemetry.track.Track.heading_rate>`). A contact (the
points under :data:`MIN_GAP_M` apart) has no direction and no own rate.
"""

from __future__ import annotations

import math

import numpy as np

from harborsight.clearance.report import STATUS_OK, SectionClearance
from harborsight.geometry.sensor_sigmas import DEAD_RECKONING_TURN_DEG_S

#: one sigma (m/s, per axis) of a vessel velocity given without one
VELOCITY_SIGMA_MPS = 0.1
#: one sigma (deg/s) of a rate of turn given without one (a rate gyro; AIS's rate of turn
#: is coarser at low rates)
YAW_RATE_SIGMA_DEG_S = 0.1
#: one sigma (deg/s) of the rate of turn of a vessel whose frame gives none (taken as 0)
UNMEASURED_TURN_DEG_S = DEAD_RECKONING_TURN_DEG_S
#: below this gap (m) a section's direction to its obstacle is not known well enough
MIN_GAP_M = 0.05


def add_own_rates(sections: list[SectionClearance], antenna_enu: np.ndarray,
                  velocity_en_mps: tuple[float, float] | None,
                  velocity_sigma_mps: float | None = None, yaw_rate_deg_s: float | None = None,
                  yaw_rate_sigma_deg_s: float | None = None, *,
                  half_lengths_m: np.ndarray | None = None, gsd_m_per_px: float = 0.0) -> None:
    """Set ``own_rate_mps`` and ``own_rate_sigma_mps`` of every ``ok`` section (module
    docstring) from the vessel's ground velocity (east, north; m/s) at its antenna
    ``antenna_enu``; nothing without a velocity. ``half_lengths_m``: half of each section's
    length, by section index; ``gsd_m_per_px``: the frame's ground sampling distance."""
    if velocity_en_mps is None:
        return
    velocity = np.asarray(velocity_en_mps, float)
    sigma_v = VELOCITY_SIGMA_MPS if velocity_sigma_mps is None else float(velocity_sigma_mps)
    turn = math.radians(yaw_rate_deg_s or 0.0)
    sigma_turn = math.radians(UNMEASURED_TURN_DEG_S if yaw_rate_deg_s is None
                              else YAW_RATE_SIGMA_DEG_S if yaw_rate_sigma_deg_s is None
                              else yaw_rate_sigma_deg_s)
    chosen = [s for s in sections if s.status == STATUS_OK and s.hull_point_enu is not None
              and s.obstacle_point_enu is not None]
    if not chosen:
        return
    hull = np.array([s.hull_point_enu for s in chosen], float)[:, :2]
    gap = np.array([s.obstacle_point_enu for s in chosen], float)[:, :2] - hull
    length = np.hypot(gap[:, 0], gap[:, 1])
    usable = (length >= MIN_GAP_M) & np.isfinite(hull).all(axis=1)
    n = gap / np.where(usable, length, 1.0)[:, None]
    r = hull - np.asarray(antenna_enu, float)[:2]
    lever = r[:, 1] * n[:, 0] - r[:, 0] * n[:, 1]              # d(v_h · n) / dψ̇
    hull_velocity = velocity + turn * np.column_stack((r[:, 1], -r[:, 0]))
    rate = -np.einsum("ij,ij->i", hull_velocity, n)
    half = (np.zeros(len(chosen)) if half_lengths_m is None
            else np.asarray(half_lengths_m, float)[[s.index for s in chosen]])
    across = hull_velocity[:, 1] * n[:, 0] - hull_velocity[:, 0] * n[:, 1]   # v_h · t
    tilt = np.minimum(gsd_m_per_px / np.where(usable, length, 1.0), 1.0)
    sigma = np.sqrt(sigma_v ** 2 + (lever * sigma_turn) ** 2 + (half * turn) ** 2
                    + (half * sigma_turn) ** 2 + (across * tilt) ** 2)
    for section, ok, rate_mps, sigma_mps in zip(chosen, usable.tolist(), rate.tolist(),
                                                sigma.tolist(), strict=True):
        if ok:
            section.own_rate_mps, section.own_rate_sigma_mps = rate_mps, sigma_mps
