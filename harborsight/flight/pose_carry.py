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
(unwrapped), on the local plane of the newest; the carried pose at ``τ`` past the newest is
that line there. Its one-sigma error (DRMS, and heading) adds in quadrature

* a floor, :data:`FLOOR_M` and :data:`FLOOR_DEG`: what a placed pose is not (the drone's
  GPS and compass drift between frames, whose error the alignment absorbed at that frame
  and not at this one; a mask's edge);
* the line's own error at ``τ``: ``σ₀ sqrt(1/n + (τ - t̄)² / Σ(t - t̄)²)`` for ``n`` poses at
  times ``t`` (mean ``t̄``), ``σ₀`` the fit's residual per pose, at least
  :data:`PLACED_NOISE_M` (:data:`PLACED_NOISE_DEG`): few poses over a short span carry far
  worse than many;
* its lag under a steady acceleration ``a`` (:data:`~harborsight.geometry.sensor_sigmas.
  DEAD_RECKONING_ACCEL_MPS2`, or the placed poses' own when they show a larger one:
  :func:`_acceleration`): a line fitted over a span ``W`` and read ``τ`` past its end
  misses ``p = a t²/2`` by ``a (τ² + W τ + W²/6) / 2`` (the least-squares line of ``t²`` on
  a uniform span); and the turn of the heading, :data:`~harborsight.geometry.
  sensor_sigmas.DEAD_RECKONING_TURN_DEG_S` ``· τ``.

It takes at least :data:`MIN_PLACED` placed poses spanning :data:`MIN_SPAN_S`, so that the
speed is measured, reaches at most :data:`CARRY_REACH_S` past the newest, and carries
nothing whose sigma is over :data:`MAX_CARRIED_SIGMA_M` (the refinement could not reach its
error): a vessel hidden for a few seconds is found again.

**Use.** Only a frame whose own vessel pose was dead-reckoned (``vessel.dead_reckoned_s``)
is carried, and only when the carried sigma is below the frame's own (its receiver's and
its dead reckoning's, in quadrature): a frame with a live fix keeps it. A frame whose own
pose can still be measured with (dead-reckoned at most 12 s) but lies more than
:data:`GATE_SIGMAS` combined sigmas (the vessel's and the drone's receivers and the carry;
heading: the vessel's and the camera's compasses and the carry) from the carried pose keeps
its own, and the carry starts again from what the images place next: the images may have
been following a sister hull the first report put them on. The carried frame is measured
like any other: refined from the carried pose, its bars from the alignment (or, where the
alignment does not place it, from the carried sigmas). What the image of a frame placed
then carries the next; a frame whose image does not place the vessel carries nothing, and
once the carried sigma is past :data:`MAX_CARRIED_SIGMA_M` the frames are the reports' again
(past 12 s from a report: not measured, until the next report). A clock that goes back by
more than :data:`CLOCK_BACK_S`, or another vessel, starts the carry again. The report says
where the pose came from (``pose_refinement.carried_from``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import pymap3d

from harborsight.clearance.measure import ClearanceSettings
from harborsight.clearance.pose_refinement import SENSORS_FIT
from harborsight.clearance.report import ClearanceReport
from harborsight.frame import FrameMetadata
from harborsight.geometry.sensor_sigmas import (
    DEAD_RECKONING_ACCEL_MPS2,
    DEAD_RECKONING_TURN_DEG_S,
    MAX_DEAD_RECKONED_S,
    SensorSigmas,
)
from harborsight.pipeline import FrameMask, measure_mask
from harborsight.vessel.spec import VesselSpec

#: one sigma of a placed pose carried to the next frame, before any motion (DRMS, m; deg)
FLOOR_M = 0.5
FLOOR_DEG = 1.0
#: the least scatter of placed poses about their line that the fit's error is reckoned with
#: (per pose; m, deg): the bench's refined poses are within a tenth of a metre
PLACED_NOISE_M = 0.15
PLACED_NOISE_DEG = 0.3
#: a carried pose less sure than this (m, DRMS) is not used: the refinement searches 2.5
#: sigma of its 3 m prior
MAX_CARRIED_SIGMA_M = 3.0
#: how many combined sigmas a frame's own measurable pose may lie from the carried one
GATE_SIGMAS = 3.0
#: how far (s) the placed poses are carried past the newest, at most (their sigma, capped
#: at :data:`MAX_CARRIED_SIGMA_M`, ends most carries sooner: 8-9 s at 2 fps): a vessel
#: hidden a few seconds under a crane or a bridge is found again
CARRY_REACH_S = 10.0
#: the placed poses the motion is fitted on: those of the last this many seconds, or the
#: newest :data:`MIN_PLACED` where they span longer, up to :data:`MAX_FIT_SPAN_S` (stills
#: taken every 2-6 s)
VELOCITY_WINDOW_S = 3.0
MAX_FIT_SPAN_S = 12.0
#: a frame this much (s) before the newest placed pose: the clock went back (a replay
#: restarted, a clock reset), and the placed poses belong to another time line
CLOCK_BACK_S = 1.0
MIN_PLACED = 3
MIN_SPAN_S = 1.0
#: the placed poses' own acceleration is estimated from those of the last this many
#: seconds (a longer span than the line's: at 2 fps and 0.15 m of scatter, 3 s of poses
#: measure an acceleration to 0.18 m/s², 6 s to about 0.03), from this many of them or more,
#: and counts when it is this many of its own sigmas from zero (with two axes, 1 % of pure
#: scatter is read as an acceleration: :func:`_acceleration`)
ACCELERATION_WINDOW_S = 6.0
MIN_FOR_ACCELERATION = 5
ACCELERATION_SIGNIFICANCE = 3.0


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


def placed_by_image(refinement: dict | None) -> bool:
    """Whether a report's pose refinement placed the vessel: applied, or found the frame's
    pose fitting as well (``SENSORS_FIT``: reached only by a fit that passed every test), and
    not contradicting it. A pose whose place along the hull the alignment held at the
    sensors' (``along_hull_held``: no edge across its length in view) was not placed along its length."""
    return bool(refinement and not refinement.get("sensors_contradicted")
                and not refinement.get("along_hull_held")
                and (refinement.get("applied") or refinement.get("reason") == SENSORS_FIT))


def placed_pose(meta: FrameMetadata, report: ClearanceReport, time_s: float) -> PlacedPose | None:
    """The vessel pose ``report``'s image placed, in ``meta``'s terms: the frame's pose moved
    by the refinement's shift (east, north on the plane of the frame's vessel antenna) and
    turned by its rotation (or the frame's own, when it fitted as well); None when the image
    did not place it (:func:`placed_by_image`)."""
    refinement = report.pose_refinement
    if not placed_by_image(refinement):
        return None
    if refinement.get("applied"):
        (east, north), turn = refinement["shift_m"], refinement["rotation_deg"]
    else:
        east, north, turn = 0.0, 0.0, 0.0
    return PlacedPose(time_s, meta.vessel_lat_deg, meta.vessel_lon_deg, (float(east), float(north)),
                      (meta.vessel_heading_deg + turn) % 360.0, meta.image)


def _line_at(t: np.ndarray, values: np.ndarray, at: float, noise_floor: float
             ) -> tuple[np.ndarray, float]:
    """Least-squares lines of ``values`` (n, k) in ``t``, read at ``at``, and one sigma of that
    reading per column's scatter (module docstring: ``σ₀ sqrt(1/n + (at - t̄)² / Sₜₜ)``, ``σ₀``
    the residual RMS over ``n - 2`` degrees of freedom, pooled over the columns, at least
    ``noise_floor``)."""
    n = len(t)
    mean_t = float(t.mean())
    s_tt = float(((t - mean_t) ** 2).sum())
    slope = ((t - mean_t) @ (values - values.mean(axis=0))) / s_tt
    intercept = values.mean(axis=0) - slope * mean_t
    residual = values - (intercept + slope * t[:, None])
    scatter = (math.sqrt(float((residual ** 2).sum()) / (values.shape[1] * (n - 2)))
               if n > 2 else 0.0)
    sigma0 = max(scatter, noise_floor)
    return intercept + slope * at, sigma0 * math.sqrt(1.0 / n + (at - mean_t) ** 2 / s_tt)


def _local_en(poses, origin: tuple[float, float]) -> np.ndarray:
    """East and north (m, ``(n, 2)``) of placed poses on the local plane at ``origin``."""
    shifts = np.array([p.shift_en_m for p in poses])
    lat, lon, _ = pymap3d.enu2geodetic(shifts[:, 0], shifts[:, 1], 0.0,
                                       np.array([p.fix_lat_deg for p in poses]),
                                       np.array([p.fix_lon_deg for p in poses]), 0.0)
    east, north, _ = pymap3d.geodetic2enu(lat, lon, 0.0, *origin, 0.0)
    return np.stack((east, north), axis=1)


def _acceleration(t: np.ndarray, values: np.ndarray, noise_floor: float) -> float:
    """The acceleration (m/s², the norm over the columns) of least-squares parabolas
    ``v = c + b t + a t²/2`` through the placed poses ``values (n, k)`` at times ``t``, when
    it is :data:`ACCELERATION_SIGNIFICANCE` of its own sigmas from zero; else 0. Its sigma
    per column is ``2 σ₀ sqrt([(XᵀX)⁻¹]₂₂)``, ``X = [1, t, t²]``, ``σ₀`` the residual per pose
    over ``n - 3`` degrees of freedom, pooled, at least ``noise_floor``. A vessel speeding up
    at 0.3 m/s² (a tug under full thrust) left a line 2.9 m behind it 3 s past the newest
    pose, with a sigma of 0.6 m from the 0.05 m/s² of dead reckoning alone."""
    n = len(t)
    if n < MIN_FOR_ACCELERATION:
        return 0.0
    design = np.column_stack((np.ones(n), t - t.mean(), (t - t.mean()) ** 2))
    coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
    residual = values - design @ coefficients
    scatter = math.sqrt(float((residual ** 2).sum()) / (values.shape[1] * (n - 3)))
    try:
        spread = float(np.linalg.inv(design.T @ design)[2, 2])
    except np.linalg.LinAlgError:
        return 0.0
    sigma_a = 2.0 * max(scatter, noise_floor) * math.sqrt(spread)
    a = 2.0 * float(np.linalg.norm(coefficients[2]))
    # the norm of k normal components of sigma sigma_a: its own spread is about sigma_a
    return a if a > ACCELERATION_SIGNIFICANCE * sigma_a else 0.0


class VesselPoseCarry:
    """The poses the images placed, and the pose they carry to a later frame (module
    docstring). One per run or live session; frames in time order."""

    def __init__(self) -> None:
        self._placed: deque[PlacedPose] = deque()
        #: the placed poses of the last :data:`ACCELERATION_WINDOW_S`, for the acceleration
        self._recent: deque[PlacedPose] = deque()
        self._vessel: str | None = None

    def forget(self) -> None:
        self._placed.clear()
        self._recent.clear()

    def took(self, meta: FrameMetadata, report: ClearanceReport, time_s: float | None) -> None:
        """Remember the pose ``report``'s image placed, if it did."""
        if time_s is None or not math.isfinite(time_s):
            return
        if report.vessel != self._vessel:
            self.forget()
            self._vessel = report.vessel
        self._forget_if_the_clock_went_back(time_s)
        if self._placed and time_s <= self._placed[-1].time_s:
            return          # out of order or repeated: a line through it would be wrong
        pose = placed_pose(meta, report, time_s)
        if pose is None:
            return
        self._placed.append(pose)
        self._recent.append(pose)
        while self._recent[0].time_s < time_s - ACCELERATION_WINDOW_S:
            self._recent.popleft()
        while self._placed and (
                self._placed[0].time_s < time_s - MAX_FIT_SPAN_S
                or (len(self._placed) > MIN_PLACED
                    and self._placed[0].time_s < time_s - VELOCITY_WINDOW_S)):
            self._placed.popleft()

    def _forget_if_the_clock_went_back(self, time_s: float | None) -> None:
        if (time_s is not None and self._placed
                and time_s < self._placed[-1].time_s - CLOCK_BACK_S):
            self.forget()

    def carried(self, time_s: float | None) -> CarriedPose | None:
        """The pose carried to ``time_s``, or None: too few placed poses, their span too
        short, ``time_s`` before the newest or beyond its reach, or its sigma too wide."""
        if time_s is None or not math.isfinite(time_s) or len(self._placed) < MIN_PLACED:
            return None
        newest = self._placed[-1]
        age = time_s - newest.time_s
        span = newest.time_s - self._placed[0].time_s
        if not 0.0 <= age <= CARRY_REACH_S or span < MIN_SPAN_S:
            return None
        t = np.array([p.time_s for p in self._placed]) - newest.time_s
        origin = newest.lat_lon_deg
        en = _local_en(self._placed, origin)
        heading = np.rad2deg(np.unwrap(np.deg2rad([p.heading_deg for p in self._placed])))
        (e, n), fit_m = _line_at(t, en, age, PLACED_NOISE_M)
        (h,), fit_deg = _line_at(t, heading[:, None], age, PLACED_NOISE_DEG)
        recent_t = np.array([p.time_s for p in self._recent]) - newest.time_s
        accel = max(DEAD_RECKONING_ACCEL_MPS2,
                    _acceleration(recent_t, _local_en(self._recent, origin), PLACED_NOISE_M))
        lag_m = 0.5 * accel * (age ** 2 + span * age + span ** 2 / 6.0)
        # fit_m is per axis: the DRMS of the two
        sigma_m = math.sqrt(FLOOR_M ** 2 + 2.0 * fit_m ** 2 + lag_m ** 2)
        if sigma_m > MAX_CARRIED_SIGMA_M:
            return None
        sigma_deg = math.sqrt(FLOOR_DEG ** 2 + fit_deg ** 2 + (DEAD_RECKONING_TURN_DEG_S * age) ** 2)
        lat, lon, _ = pymap3d.enu2geodetic(e, n, 0.0, *origin, 0.0)
        return CarriedPose(float(lat), float(lon), float(h) % 360.0, sigma_m, sigma_deg,
                           float(age), newest.image)

    def prior_for(self, meta: FrameMetadata, time_s: float | None, own: SensorSigmas,
                  vessel: str) -> tuple[FrameMetadata, CarriedPose | None, str | None]:
        """``meta`` with the carried pose, when its own vessel pose was dead-reckoned and the
        carried one is better than ``own`` (the frame's sigmas as it came); else ``meta``.
        The third item is a warning when the frame's own measurable pose disagreed with the
        carried one, which was then dropped (module docstring)."""
        if vessel != self._vessel:
            self.forget()
            self._vessel = vessel
        self._forget_if_the_clock_went_back(time_s)
        if not meta.vessel_dead_reckoned_s:
            return meta, None, None
        carried = self.carried(time_s)
        if carried is None or carried.sigma_m >= own.vessel_gps:
            return meta, None, None
        if meta.vessel_dead_reckoned_s <= MAX_DEAD_RECKONED_S:
            disagreement = _disagreement(meta, carried, own)
            if disagreement is not None:
                self.forget()
                return meta, None, disagreement
        sigmas = dict(meta.sensor_sigmas, vessel_gps=carried.sigma_m / math.sqrt(2.0),
                      vessel_heading_deg=carried.heading_sigma_deg)
        return replace(meta, vessel_lat_deg=carried.lat_deg, vessel_lon_deg=carried.lon_deg,
                       vessel_heading_deg=carried.heading_deg, vessel_dead_reckoned_s=None,
                       sensor_sigmas=sigmas), carried, None


    def measure(self, mask: FrameMask, meta: FrameMetadata, vessel: VesselSpec,
                settings: ClearanceSettings, time_s: float | None
                ) -> tuple[ClearanceReport, str | None]:
        """``mask`` measured (:func:`~harborsight.pipeline.measure_mask`) with the carried
        pose where it applies (:meth:`prior_for`), the report saying so, and what its image
        placed taken for the frames after; with the warning of a disagreeing report, or None.
        What `run` and the live aid do with every frame."""
        meta, carried, disagreement = self.prior_for(meta, time_s, settings.sensor_sigmas(meta),
                                                     vessel.name)
        report = measure_mask(mask, meta, vessel, settings)
        note_carried(report, carried)
        self.took(meta, report, time_s)
        return report, disagreement


def _disagreement(meta: FrameMetadata, carried: CarriedPose, own: SensorSigmas) -> str | None:
    """Why the frame's own vessel pose and the carried one cannot both be right: more than
    :data:`GATE_SIGMAS` combined sigmas apart in position (the vessel's and the drone's
    receivers, DRMS, and the carry's) or heading (the vessel's and the camera's compasses
    and the carry's); None when they agree."""
    east, north, _ = pymap3d.geodetic2enu(carried.lat_deg, carried.lon_deg, 0.0,
                                          meta.vessel_lat_deg, meta.vessel_lon_deg, 0.0)
    apart_m = math.hypot(float(east), float(north))
    limit_m = GATE_SIGMAS * math.hypot(own.vessel_gps, own.uav_gps, carried.sigma_m)
    turn_deg = abs((carried.heading_deg - meta.vessel_heading_deg + 180.0) % 360.0 - 180.0)
    limit_deg = GATE_SIGMAS * math.hypot(own.vessel_heading_deg, own.camera_yaw_deg,
                                         carried.heading_sigma_deg)
    if apart_m <= limit_m and turn_deg <= limit_deg:
        return None
    return (f"the vessel's report lies {apart_m:.1f} m and {turn_deg:.1f} deg from the pose the "
            f"images carried (more than {limit_m:.1f} m or {limit_deg:.1f} deg): the report is "
            "taken, and the carry starts again from what the images place next")


def note_carried(report: ClearanceReport, carried: CarriedPose | None) -> None:
    """Say in ``report`` where its vessel pose came from, when it was carried."""
    if carried is not None and report.pose_refinement is not None:
        report.pose_refinement["carried_from"] = carried.to_dict()
