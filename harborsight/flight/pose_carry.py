"""The vessel's pose carried from frame to frame by the images, between sparse reports.

A vessel known from AIS has a position every 10 s (class A under way) or every 30 s to
3 min (class B; 3 min under 2 kn, which is how a vessel berths); between reports it is
dead-reckoned, and beyond :data:`~harborsight.geometry.sensor_sigmas.MAX_DEAD_RECKONED_S`
its pose is not good enough to measure with. But every frame the pose refinement placed
on the vessel's own ship pixels says where the vessel was, relative to the drone, to about
a tenth of a metre: the frames that follow can start from there.

**Model.** The poses the image placed (the refinement applied, or found the frame's pose
fitting as well after every test of the fit, ``SENSORS_FIT``) in the last
:data:`VELOCITY_WINDOW_S` (or the newest :data:`MIN_PLACED`, up to :data:`MAX_FIT_SPAN_S`
old: stills every 2 s) are fitted with a straight line in time, east, north and heading
(unwrapped), on the local plane of the newest; the carried pose at ``t`` is that
line at ``t``, and its one-sigma error (DRMS, and heading)

    σ_p = sqrt(FLOOR_M² + drift_p(τ)²),   σ_ψ = sqrt(FLOOR_DEG² + drift_ψ(τ)²)

with ``τ`` the time since the newest placed pose and ``drift`` the dead-reckoning drift
(:func:`~harborsight.geometry.sensor_sigmas.dead_reckoning_drift`: a speed known to
0.1 m/s, a change of speed of 0.05 m/s², a turn of 0.5°/s). The floors stand for what the
placed pose is not: the drone's own GPS and compass drift between frames (the refinement
absorbed their error at that frame, not at this one) and a mask's edge. It takes at least
:data:`MIN_PLACED` placed poses spanning :data:`MIN_SPAN_S`, so that the speed is measured,
and reaches :data:`CARRY_REACH_S` past the newest.

**Use.** Only a frame whose own vessel pose was dead-reckoned (``vessel.dead_reckoned_s``)
is carried, and only when the carried sigma is below the frame's own (its receiver's and
its dead reckoning's, in quadrature): a frame with a live fix keeps it. The carried frame
is measured like any other: refined from the carried pose, its bars from the alignment
(or, where the alignment does not place it, from the carried sigmas). What the image of a
frame placed then carries the next; a frame whose image does not place the vessel carries
nothing, and after :data:`CARRY_REACH_S` without one the frames are the reports' again.
The report says where the pose came from (``pose_refinement.carried_from``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import pymap3d

from harborsight.clearance.pose_refinement import SENSORS_FIT
from harborsight.clearance.report import ClearanceReport
from harborsight.frame import FrameMetadata
from harborsight.geometry.sensor_sigmas import SensorSigmas, dead_reckoning_drift

#: one sigma of a placed pose carried to the next frame, before any motion (DRMS, m; deg)
FLOOR_M = 0.5
FLOOR_DEG = 1.0
#: how far (s) the placed poses are carried past the newest
CARRY_REACH_S = 5.0
#: the placed poses the motion is fitted on: those of the last this many seconds, or the
#: newest :data:`MIN_PLACED` where they span longer, up to :data:`MAX_FIT_SPAN_S` (stills
#: taken every 2 s)
VELOCITY_WINDOW_S = 3.0
MAX_FIT_SPAN_S = 8.0
MIN_PLACED = 3
MIN_SPAN_S = 1.0


@dataclass(frozen=True)
class PlacedPose:
    """A vessel pose a frame's image placed: time (s, the run's clock), the frame's vessel
    fix and the image's shift of it (east, north on the fix's local plane; turned into a
    position only when a carry needs it), and the heading."""

    time_s: float
    fix_lat_deg: float
    fix_lon_deg: float
    shift_en_m: tuple[float, float]
    heading_deg: float
    image: str

    @property
    def lat_lon_deg(self) -> tuple[float, float]:
        lat, lon, _ = pymap3d.enu2geodetic(*self.shift_en_m, 0.0, self.fix_lat_deg,
                                           self.fix_lon_deg, 0.0)
        return float(lat), float(lon)


@dataclass(frozen=True)
class CarriedPose:
    """The pose carried to a frame, and from where."""

    lat_deg: float
    lon_deg: float
    heading_deg: float
    sigma_m: float              # DRMS
    heading_sigma_deg: float
    age_s: float                # since the newest placed pose
    image: str                  # that pose's frame

    def to_dict(self) -> dict:
        return {"image": self.image, "age_s": round(self.age_s, 3),
                "sigma_m": round(self.sigma_m, 3),
                "heading_sigma_deg": round(self.heading_sigma_deg, 3)}


def placed_pose(meta: FrameMetadata, report: ClearanceReport, time_s: float) -> PlacedPose | None:
    """The vessel pose ``report``'s image placed, in ``meta``'s terms: the frame's pose moved
    by the refinement's shift (east, north on the plane of the frame's vessel antenna) and
    turned by its rotation, or the frame's own where the alignment found it fitting as well
    (``SENSORS_FIT``: reached only by a fit that passed every test); None when the image did
    not place it, or contradicted the frame's pose."""
    refinement = report.pose_refinement
    if not refinement or report.sensors_contradicted:
        return None
    if refinement.get("applied"):
        (east, north), turn = refinement["shift_m"], refinement["rotation_deg"]
    elif refinement.get("reason") == SENSORS_FIT:
        east, north, turn = 0.0, 0.0, 0.0
    else:
        return None
    return PlacedPose(time_s, meta.vessel_lat_deg, meta.vessel_lon_deg, (float(east), float(north)),
                      (meta.vessel_heading_deg + turn) % 360.0, meta.image)


class VesselPoseCarry:
    """The poses the images placed, and the pose they carry to a later frame (module
    docstring). One per run or live session; frames in time order."""

    def __init__(self) -> None:
        self._placed: deque[PlacedPose] = deque()

    def forget(self) -> None:
        self._placed.clear()

    def took(self, meta: FrameMetadata, report: ClearanceReport, time_s: float | None) -> None:
        """Remember the pose ``report``'s image placed, if it did."""
        if time_s is None or not math.isfinite(time_s):
            return
        if self._placed and time_s <= self._placed[-1].time_s:
            return          # out of order or repeated: a line through it would be wrong
        pose = placed_pose(meta, report, time_s)
        if pose is None:
            return
        self._placed.append(pose)
        while self._placed and (
                self._placed[0].time_s < time_s - MAX_FIT_SPAN_S
                or (len(self._placed) > MIN_PLACED
                    and self._placed[0].time_s < time_s - VELOCITY_WINDOW_S)):
            self._placed.popleft()

    def carried(self, time_s: float | None) -> CarriedPose | None:
        """The pose carried to ``time_s``, or None: too few placed poses, their span too
        short, or ``time_s`` before the newest or beyond its reach."""
        if time_s is None or len(self._placed) < MIN_PLACED:
            return None
        newest = self._placed[-1]
        age = time_s - newest.time_s
        span = newest.time_s - self._placed[0].time_s
        if not 0.0 < age <= CARRY_REACH_S or span < MIN_SPAN_S:
            return None
        t = np.array([p.time_s for p in self._placed]) - newest.time_s
        shifts = np.array([p.shift_en_m for p in self._placed])
        lat, lon, _ = pymap3d.enu2geodetic(
            shifts[:, 0], shifts[:, 1], 0.0, np.array([p.fix_lat_deg for p in self._placed]),
            np.array([p.fix_lon_deg for p in self._placed]), 0.0)
        origin = (float(lat[-1]), float(lon[-1]))
        east, north, _ = pymap3d.geodetic2enu(lat, lon, 0.0, *origin, 0.0)
        heading = np.rad2deg(np.unwrap(np.deg2rad([p.heading_deg for p in self._placed])))
        # least-squares lines in time, read at ``age`` past the newest
        design = np.stack((np.ones_like(t), t), axis=1)
        coef, *_ = np.linalg.lstsq(design, np.stack((east, north, heading), axis=1), rcond=None)
        e, n, h = coef[0] + coef[1] * age
        lat, lon, _ = pymap3d.enu2geodetic(e, n, 0.0, *origin, 0.0)
        drift_m, drift_deg = dead_reckoning_drift(age)
        return CarriedPose(float(lat), float(lon), float(h) % 360.0, math.hypot(FLOOR_M, drift_m),
                           math.hypot(FLOOR_DEG, drift_deg), float(age), newest.image)

    def prior_for(self, meta: FrameMetadata, time_s: float | None, own: SensorSigmas
                  ) -> tuple[FrameMetadata, CarriedPose | None]:
        """``meta`` with the carried pose, when its own vessel pose was dead-reckoned and the
        carried one is better than ``own`` (the frame's sigmas as it came); else ``meta``."""
        if not meta.vessel_dead_reckoned_s:
            return meta, None
        carried = self.carried(time_s)
        if carried is None or carried.sigma_m >= own.vessel_gps:
            return meta, None
        sigmas = dict(meta.sensor_sigmas, vessel_gps=carried.sigma_m / math.sqrt(2.0),
                      vessel_heading_deg=carried.heading_sigma_deg)
        return replace(meta, vessel_lat_deg=carried.lat_deg, vessel_lon_deg=carried.lon_deg,
                       vessel_heading_deg=carried.heading_deg, vessel_dead_reckoned_s=None,
                       sensor_sigmas=sigmas), carried


def note_carried(report: ClearanceReport, carried: CarriedPose | None) -> None:
    """Say in ``report`` where its vessel pose came from, when it was carried."""
    if carried is not None and report.pose_refinement is not None:
        report.pose_refinement["carried_from"] = carried.to_dict()
