"""Per-section tracking of clearance and closing speed over time (a gated Kalman filter).

Each track holds ``x = [d, ḋ]`` (clearance in metres and its rate; closing speed is ``-ḋ``)
under a constant-velocity model with white acceleration of spectral density
``q = accel_sigma_mps2²``:

    F = [[1, Δt], [0, 1]],   Q = q · [[Δt³/3, Δt²/2], [Δt²/2, Δt]]

and a reading ``z = d + e`` of variance ``R = sigma_random² + sigma_systematic² · min(1, Δt/τ)``.
The frame-to-frame part of a reading's error (pixel grid, mask edge, the pose alignment) is
white; the sensors' part (GPS, compasses, height) drifts with correlation time ``τ``
(``drift_time_s``), so only what it can change between two readings enters ``R``. The
reported ``sigma`` of a filtered distance adds the latest reading's systematic part back:
averaging frames does not remove a GPS bias.

The white part is also measured from the track's own readings. A reading's ``sigma_random``
is a per-frame model of its error (the alignment's covariance, the mask's doubt); much of
that error repeats from one frame to the next, because the scene, the mask and the alignment
barely change in half a second (on the 100 m berthing flight the model says 1.1-1.2 m while
the readings scatter by 0.1 m about a smooth curve). Treating it all as white makes the filter
trust new readings too little: it lags, and overshoots when the vessel stops. So each track
keeps its last ``noise_window`` readings and takes, for each three in a row, the residual of
the middle one from the straight line through its neighbours,

    r = (z₂ - (a·z₁ + b·z₃)) / √(1 + a² + b²),   a = (t₃ - t₂)/(t₃ - t₁),  b = 1 - a,

whose variance is the white variance whatever the speed (a constant rate cancels); a change of
speed spoils the one or two residuals around it, which the robust spread
``σ̂ = 1.4826 · median |r|`` ignores. ``σ̂`` from a dozen residuals scatters (its 10-90 % range
is 0.6-1.6 σ), so ``R`` takes the upper bound ``noise_margin · σ̂`` (at least
``min_reading_sigma_m``) where that is below the model's ``sigma_random``, once there are
``min_noise_residuals`` residuals. When the model is honest the bound nearly always lies above
it and the model's value stands (with a margin of 1.5 instead of 2, a low draw took over often
enough to raise the closing speed's error on honest 0.3 m readings by 5-30 %). What the
model says beyond ``R`` counts as systematic, so the reported sigma keeps it: the filtered
sigma then no longer shrinks by averaging errors that repeat from frame to frame.

The gate still uses the model's variance, so which reading belongs to which track does not
hinge on a few frames' scatter. A *farther* reading inside that gate but beyond
``robust_sigma`` of ``S = P + R`` (a mask that lost a metre of quay for one frame) would pull
hard on the closing speed, so its ``R`` is raised until its normalised innovation is
``robust_sigma``: ``R' = min(R_model, max(R, (z - d̂)²/c² - P))``. Its pull on the state is
then ``P·c²/(z - d̂)``, less the farther it lies, and never less than under the model's own
``R``. A *nearer* reading is never capped: the filter follows a nearer obstacle at once.
On the three berthing flights (docs/results.md) this took the filtered MAE at 100 m from 0.41
to 0.33 m and at 60 m from 0.31 to 0.30 m; the closing speed's median error per frame grew
from 0.005-0.011 to 0.010-0.044 m/s.

Manoeuvres. A constant-velocity filter lags when the obstacle's motion changes at once: a
vessel that stops at its berth leaves a steady approach's prediction by its speed times the
frame interval, every frame. The robust cap took those farther readings for outliers and
precise ones fell beyond the gate and were held back as a farther obstacle, so on the
berthing flights 0.2-0.36 m/s was still shown 3 s after the stop, and the filtered distance
ran 0.2-0.4 m short. Each track therefore keeps the normalised innovations
``ν = (z - d̂)/√(P + R)`` of the readings since its last manoeuvre, also of the readings the
current track did not take. When the last ``n >= 2`` of them, spanning 0.4 to 1 s, lie on one
side with ``|Σν| / √n`` beyond ``manoeuvre_sigma`` (each ν clipped to the gate), the track
restarts from the straight line fitted to those readings (its slope and its distance now,
with their least-squares covariance under ``R``), provided that the line's speed differs
from the track's by at least 2.5 times its own sigma (the readings' measured scatter: a line
through noisy readings says little, and a needless restart costs the speed's accuracy for
many frames), by at most ``manoeuvre_max_mps``, and that the line run back to the track's
last reading before them meets it within the gate (else the readings are of another
obstacle, a quay behind a boat that left the band, which the gate's rules handle).

Gating and tracks. A section may hold several tracks (obstacles): a reading updates the
likeliest track among those whose normalised innovation ``ν = |z - d̂| / sqrt(S)`` is within
``gate_sigma``, the one of least ``ν² + ln S`` (by ``ν`` alone a track just started, its
``S`` wide, took readings from an established track of the same obstacle, and at 10 Hz two
tracks traded one quay's readings); else it starts a new track. Which track is *current*
(reported):

* the track a reading updated;
* a reading **nearer** than the current track's prediction, beyond the gate, is reported at
  once from its new track: the filter never hides a nearer obstacle (a boat entering the
  band, or a false alarm, which errs on the safe side);
* a reading **farther** than the prediction, beyond the gate, is held back as an outlier:
  the current track coasts on its prediction (``state = "held"``) until ``confirm_frames``
  readings in a row agree with the new track instead;
* but a current track born of **one** reading (a nearer obstacle seen once) that the very
  next reading contradicts, by updating an established track, was a one-frame glitch (a
  blob of glare or wake the model took for solid): it is dropped and the established track
  is current again. A real obstacle seen twice is held like any other. (On the bundled
  demo flight with the shipped model this took the filtered MAE from 0.372 to 0.336 m: one
  false 1.8 m reading had been held for two more frames against a quay 9 m off.)
* a track with no reading for ``max_coast_s`` is dropped; a section out of view, or cut by
  the image's edge, coasts its current track meanwhile (``state = "coasting"``). A section
  measured ``clear`` is evidence, not absence: a current track predicted where its band was
  seen clear (:func:`seen_clear`) is no longer reported (``state = "clear"``), so a boat
  that left the band is not coasted into "contact in 0 s" (it was, for 5 s); the track
  stays, to take its obstacle again should the mask have missed it for a frame;
* a track seen once that the next reading does not take is dropped (it was an outlier's:
  kept, it took a later reading that strayed from the right track and showed motion it
  made up, the filtered distance 0.85 m short);
* the current track seen once takes a reading beyond its gate when the two mean a change
  of at most ``max_speed_mps``, its speed started from the two: a boat closing at 4 m/s is
  2 m nearer each half second, beyond the first gate, and never got a closing speed.
  The second reading also starts a track of its own (the first may have been the glitch),
  which takes the next reading when that is clearly likelier from it
  (:data:`ALTERNATIVE_PENALTY`), and a line that the very next reading contradicts (it goes
  to another track) is dropped: a glitch on a section's first reading, 4 m too far, had the
  line coast a phantom approach to 0 m, and at 10 Hz show 7 m/s and contact in 1.1 s;
* a reading beyond the gate of a current track that is still young (2 to
  :data:`LINE_START_READINGS` readings) starts a track on the line through that track's
  readings and it, when the reading lies within the gate of the line through the track's
  readings alone (:meth:`SectionTracker._line_start`): at 10 Hz a fast boat lay inside a
  young track's gate for a frame or two and beyond it the next, and each new track started
  again near 0 m/s. The line's slope is at most ``max_speed_mps``. The young track stays
  beside it; until the line has taken :data:`LINE_CONFIRM_READINGS` more readings spanning
  :data:`LINE_CONFIRM_SPAN_S`, each is weighed as from the line and as from a still
  obstacle where its readings lie, and the line becomes a track of its readings alone once
  the still obstacle is the likelier over them (:meth:`SectionTracker._still_hypothesis`;
  a still boat 2 m in front of a young quay had otherwise shown 10 m/s and contact in
  0.5 s); its speed is not shown meanwhile, and a reading another track takes drops it;
* a track born of a reading beyond the current track's gate has that track as its rival
  while young: when the readings it takes after its first lie within 2 sigma of the
  rival's predictions (``|Σν| / √n``), they go to the rival and the young track is dropped
  (:meth:`SectionTracker._rival_if_alike`; its first reading was chosen for lying beyond
  the gate, so it says nothing); and of two tracks whose predicted distance and rate agree
  within 2 sigma, the less certain goes (:meth:`SectionTracker._merge_alike`). At 10 Hz
  both had left two tracks of one quay side by side for seconds, trading its readings;
* a reading whose time is uncertain (``Reading.time_sigma_s``: frames stamped to the whole
  second at several a second) has ``(ḋ² + P_ḋḋ) σ_t²`` added to its ``R`` and to the
  reported sigma.

So a boat passing between the hull and a quay takes its own track, and the quay's track
keeps its closing speed and resumes when the quay is seen again. A closing speed is
reported once a track has ``min_updates`` readings; time to contact is ``d̂ / closing speed``
while the closing speed exceeds ``min_closing_mps``.

The vessel's own motion (docs/geometry.md has the whole of it). A reading may carry the rate
``r`` at which the vessel's own velocity and turn change the gap, were the obstacle fixed
(:func:`harborsight.clearance.own_motion.add_own_rates`). The state is then
``[d, w, r]``, ``w`` what is left of the rate (the obstacle's own motion), taken with a small
white acceleration (``obstacle_accel_sigma_mps2``: a quay does not move), so that the model's
drift as the gap narrows stays out of the closing speed. That stiffness would make a boat
that starts to move slowly, under the manoeuvre rule's reach, a slow learner: with readings
scattering by 0.3 m at 2 Hz, a start to 0.3 m/s was shown within 0.1 m/s after 7.5 s, against
4 s without own rates. So each such track runs Page's one-sided test on the normalised
innovations of the readings it takes, nearer ``g⁺ = max(0, g⁺ + (-ν - k) a)`` and farther
``g⁻ = max(0, g⁻ + (ν - k) a)`` (``k`` = :data:`DRIFT_ALLOWANCE`, each ``ν`` clipped to the
gate, ``a`` a reading's weight, below); when one sum passes :data:`DRIFT_THRESHOLD`, ``w``
gets the variance the agile acceleration (``accel_sigma_mps2``) would have given it since
that sum's run began and keeps that acceleration for :data:`DRIFT_AGILE_S`, so that the
readings after the alarm move ``w`` (the same start: 5.5 s). A lower threshold learns no
sooner and fires more often on errors that repeat from frame to frame.

Frame rate. The manoeuvre rule and the drift test add up normalised innovations as if each
reading were an independent look, and the noise residuals take consecutive readings. At 10
frames a second a mask's error repeats from one frame to the next: with readings whose
0.3 m error wanders with a correlation time of 1 s, a fixed quay showed more than 0.1 m/s of
closing speed on 69 % of the frames (the manoeuvre rule firing on each wander, and the
residuals of readings 0.1 s apart measuring almost no noise), against 1.4 % at 2 Hz. So
readings closer together than :data:`EVIDENCE_STEP_S` (0.5 s) count in proportion: ``n``
of them spanning ``T`` are worth ``min(n, 1 + T / EVIDENCE_STEP_S)`` to the manoeuvre rule
(its ``|Σν| / √n`` becomes the mean ``ν`` times the square root of that, and the line's
variances grow by ``n / n_eff``), a reading ``Δt`` after the track's last weighs
``a = min(1, Δt / EVIDENCE_STEP_S)`` in the drift test's sums, and the three-point residuals
take readings at least :data:`NOISE_SPACING_S` apart. Readings 0.5 s or more apart are
taken as before, to the bit; at 10 Hz that quay shows 7 %.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from harborsight.flight.track import (
    LINE_CONFIRM_READINGS,
    LINE_CONFIRM_SPAN_S,
    LINE_START_READINGS,
    MANOEUVRE_SPEED_SIGMA,
    FittedLine,
    Track,
    independent_count,
    manoeuvre_readings,
)
from harborsight.flight.tracker_inputs import (
    Reading,
    SectionEstimate,
    TrackerSettings,
    distance_rate,
    own_rate_of,
    sane_reading,
    timing_variance,
)

#: what the steady alternative of a two-point line (the second reading alone) gives away
#: in the association's ``ν² + ln S``: it takes the third reading when that is e^(x/2)
#: times likelier from it than from the line
ALTERNATIVE_PENALTY = 2.0
#: a young track whose readings after its first lie within this many sigma of its rival's
#: predictions (:meth:`SectionTracker._rival_if_alike`) is the rival's
RIVAL_SIGMA = 2.0
#: two tracks whose predicted distance and rate lie within this Mahalanobis distance of
#: each other are one obstacle's (:meth:`SectionTracker._merge_alike`)
MERGE_SIGMA = 2.0


@dataclass
class SectionTracker:
    """The tracks of one section (module docstring)."""

    settings: TrackerSettings = field(default_factory=TrackerSettings)
    tracks: list[Track] = field(default_factory=list)
    current: Track | None = None
    _next_id: int = 0
    #: this step's reading's own rate and sigma (None: none, or no reading)
    _own: tuple[float, float] | None = None
    #: this step's reading's time sigma (s; 0 without a reading)
    _time_sigma_s: float = 0.0

    def _reading_variance(self, reading: Reading, dt: float, track: Track | None = None,
                          measured: bool = True) -> tuple[float, float]:
        """``R`` of a reading ``dt`` after the track's last (a negative ``dt``, a frame a
        little out of order, counts as 0), and the reading's systematic sigma. A reading
        without a sigma (a pixel past a lens's fold) is no surer than ``track``'s last
        reading, or than :attr:`TrackerSettings.unknown_reading_sigma_m` when no track
        says; with ``measured``, the track's measured white noise caps the model's (module
        docstring; the gate uses the model's alone)."""
        s = self.settings
        random = reading.sigma_random_m
        total = reading.sigma_m if reading.sigma_m is not None else random
        if total is None and track is not None and track.last_sigmas is not None:
            total, random = track.last_sigmas
        if total is None:
            total = s.unknown_reading_sigma_m
        random = max(total if random is None else min(random, total), s.min_reading_sigma_m)
        white = (track.white_variance(s.min_noise_residuals)
                 if measured and track is not None and s.noise_window else None)
        if white is not None:
            random = min(random, max(s.noise_margin * math.sqrt(white), s.min_reading_sigma_m))
        systematic2 = max(total ** 2 - random ** 2, 0.0)
        variance = random ** 2 + systematic2 * min(1.0, max(dt, 0.0) / s.drift_time_s)
        if track is not None:         # a time known to sigma_t moves the distance by ḋ σ_t
            variance += timing_variance(track.state, track.covariance, reading.time_sigma_s)
        return variance, math.sqrt(systematic2)

    def _new_track(self, time_s: float, reading: Reading) -> Track:
        """A track of its own for ``reading``, joining the section's (:meth:`_add`)."""
        track = self._fresh_track(time_s, reading, self._next_id)
        self._add(track)
        return track

    def _fresh_track(self, time_s: float, reading: Reading, ident: int) -> Track:
        # the bias is added later; a reading without a sigma is no surer than the current's
        variance, systematic = self._reading_variance(reading, 0.0, self.current, measured=False)
        # with the vessel's own rate, the obstacle is taken as fixed until its readings say
        # otherwise (w = 0); without, the distance as unchanging (its rate 0): either way
        # within initial_speed_sigma_mps
        s = self.settings
        own = own_rate_of(reading)
        track = Track(ident, time_s, np.array([reading.distance_m, 0.0, 0.0]),
                       np.diag([variance, s.initial_speed_sigma_mps ** 2, 0.0]),
                       systematic_m=systematic,
                       last_sigmas=(None if reading.sigma_m is None
                                    else (reading.sigma_m, reading.sigma_random_m)),
                       residuals=deque(maxlen=max(s.noise_window - 2, 0)),
                       accel_q=s.accel_sigma_mps2 ** 2, obstacle_q=s.obstacle_accel_sigma_mps2 ** 2,
                       own_q=s.accel_sigma_mps2 ** 2, own_gate=s.gate_sigma)
        if own is not None:
            track.state[2], track.covariance[2, 2], track.has_own = own[0], own[1] ** 2, True
            track.own_time_s = time_s
        track.remember(time_s, reading.distance_m)
        return track

    def _add(self, track: Track) -> None:
        """A new track (ident ``_next_id``) joins the section's; beyond
        :attr:`TrackerSettings.max_tracks` the stalest other than it and the current goes."""
        self._next_id += 1
        self.tracks.append(track)
        if len(self.tracks) > self.settings.max_tracks:      # drop the stalest other track
            others = [t for t in self.tracks if t is not track and t is not self.current]
            self.tracks.remove(min(others or [t for t in self.tracks if t is not track],
                                   key=lambda t: t.time_s))

    def step(self, time_s: float, reading: Reading | None,
             seen_clear: tuple[float, float] | None = None) -> SectionEstimate:
        """Advance to ``time_s`` (non-decreasing) with this frame's reading, or None when
        the section has none (not ok, or cut by the image edge). ``seen_clear`` ``(from_m,
        to_m)``: the section was measured clear, its water seen from ``from_m`` (where the
        vessel stops hiding it) out to ``to_m``; a current track predicted in that range is
        no longer reported (a boat that left the band), not coasted into contact."""
        s = self.settings
        # a track whose clock is far ahead (it took a frame stamped in the future, a bad GPS
        # time) goes too: every later reading would be taken at its clock, with no motion
        self.tracks = [t for t in self.tracks if abs(time_s - t.time_s) <= s.max_coast_s]
        if reading is not None:
            reading = sane_reading(reading)
        self._own = own_rate_of(reading)
        self._time_sigma_s = reading.time_sigma_s if reading is not None else 0.0
        if reading is not None:
            self._merge_alike(time_s)
        if self.current is not None and self.current not in self.tracks:
            self.current = None
        if reading is None and seen_clear is not None and self.current is not None:
            near_m, far_m = seen_clear
            if near_m <= self._predicted(self.current, time_s)[0][0] < far_m:
                # seen clear where the track would be: not coasted, no longer reported; it
                # stays to take the obstacle again should a mask have missed it a frame
                self.current = None
        if reading is None:
            if self.current is not None:
                return self._estimate(time_s, "coasting")
            return SectionEstimate(state="clear" if seen_clear is not None else "none")

        current = self.current
        surprise = self._surprise(current, time_s, reading) if current is not None else None
        restart = (self._manoeuvre(current, time_s, reading, *surprise)
                   if surprise is not None else None)
        two_point_started = False
        if restart is not None:
            self._restart(current, time_s, reading, restart)
            best, state = current, "updated"
        else:
            best, best_score, best_cost = None, math.inf, math.inf
            innovations, line_margin = {}, {}
            for track in self.tracks:
                x, P = self._predicted(track, time_s)
                variance, _ = self._reading_variance(reading, time_s - track.time_s, track,
                                                     measured=False)
                spread = P[0, 0] + variance
                innovations[track.ident] = (reading.distance_m - x[0]) / math.sqrt(spread)
                if track.line_readings is not None:
                    # a line start not yet confirmed: its line, or a still obstacle where its
                    # readings lie, whichever is likelier (_still_hypothesis)
                    nu, still_spread = self._still_hypothesis(track, time_s, reading, x, variance)
                    margin = (innovations[track.ident] ** 2 + math.log(spread)
                              - nu * nu - math.log(still_spread))
                    line_margin[track.ident] = margin
                    if margin > 0:
                        innovations[track.ident], spread = nu, still_spread
                score = abs(innovations[track.ident])
                # the reading goes to the track most likely to have given it, ν² + ln S
                # (twice the negative log-likelihood): by ν alone a track just started,
                # whose wide S shrinks every ν, took readings from an established track of
                # the same obstacle, and two tracks then traded one quay's readings
                cost = (score * score + math.log(spread)
                        + (track.association_penalty if track.updates == 1 else 0.0)
                        if score <= s.gate_sigma else math.inf)
                if cost < best_cost or (best_cost == math.inf and score < best_score):
                    best, best_score, best_cost = track, score, cost
            if best is not None and best_score <= s.gate_sigma:
                best = self._rival_if_alike(best, innovations)
                if best.line_readings is not None:
                    # the line against a still obstacle, over the readings since it began
                    best.line_evidence += line_margin[best.ident]
                    if best.line_evidence > 0:
                        best = self._rival_if_alike(self._as_still(best), innovations)
                self._update(best, time_s, reading)
                if best.line_readings is not None:
                    best.line_readings.append((time_s, reading, reading.distance_m - best.own_travel_m))
                    if (len(best.line_readings) > LINE_CONFIRM_READINGS
                            and time_s - best.line_readings[0][0] >= LINE_CONFIRM_SPAN_S - 1e-9):
                        best.line_readings = None          # confirmed: its speed is shown
                state = "updated"
            else:
                best = self._two_point_start(time_s, reading)
                two_point_started = best is not None
                if best is None:
                    best = self._line_start(time_s, reading)
                state = "updated" if best is not None else "new"
                if best is None:
                    rival = self.current
                    best = self._new_track(time_s, reading)
                    best.rival = None if rival is None else rival.ident
            if surprise is not None and best is not current:
                # a reading the current track did not take still tells of its motion: a
                # stopped vessel's readings leave a steady approach's gate
                current.surprises.append((time_s, reading.distance_m, surprise[0], False,
                                          current.own_travel_to(
                                              time_s, self._predicted(current, time_s)[0])))
        for track in list(self.tracks):
            if track is not best:
                track.misses_in_row += 1
                if track.updates == 1 and track is not self.current:
                    # seen once, then not: an outlier's track would take a later reading
                    # that strays from the right track and show motion it made up
                    self.tracks.remove(track)
        if restart is None and two_point_started:
            # the other reading of the two may be the glitch: the reading also starts a track
            # of its own, and the next reading goes to the likelier of the two
            self._new_track(time_s, reading).association_penalty = ALTERNATIVE_PENALTY
        if self._takes_over(best, time_s):
            self.current = best
            return self._estimate(time_s, state)
        return self._estimate(time_s, "held")

    def _rival_if_alike(self, track: Track, innovations: dict[int, float]) -> Track:
        """The track to take this reading, which the association gave ``track``: its rival
        instead, and ``track`` dropped, when ``track`` is young (under
        :data:`LINE_START_READINGS` readings), was born of a reading beyond the gate of the
        track then current (its rival, still kept), and the readings it took since its
        first, this one included, lie within :data:`RIVAL_SIGMA` of the rival's
        predictions: ``|Σν| / √n``, ``ν`` each one's normalised innovation from the rival.
        Its first reading was chosen for lying beyond the rival's gate, so it says nothing of
        which is right; the ones after it do. At 10 Hz a quay's reading 3 sigma nearer
        started a track, the next reading (2 sigma nearer, as likely from the quay) went to
        it, and the two tracks lived on side by side for seconds, trading the quay's
        readings. A reading beyond the rival's gate confirms ``track``: it is tested no
        more."""
        rival_ident = track.rival
        if rival_ident is None or track.updates >= LINE_START_READINGS:
            return track
        rival = next((t for t in self.tracks if t.ident == rival_ident and t is not track), None)
        if not self._count_against_rival(track, None if rival is None else innovations.get(rival_ident)):
            return track
        if abs(track.rival_sum) > RIVAL_SIGMA * math.sqrt(track.rival_count):
            return track
        self.tracks.remove(track)
        if self.current is track:
            self.current = rival
        return rival

    def _count_against_rival(self, track: Track, nu: float | None) -> bool:
        """Add a reading's normalised innovation ``nu`` from ``track``'s rival to the rival
        test's sums; a reading beyond the rival's gate (or none, the rival gone) confirms
        ``track``, which is tested no more. Whether it is still on test."""
        if nu is None or abs(nu) > self.settings.gate_sigma:
            track.rival = None
            return False
        track.rival_sum += nu
        track.rival_count += 1
        return True

    def _merge_alike(self, time_s: float) -> None:
        """Of two tracks that predict the same distance and rate at ``time_s`` within
        :data:`MERGE_SIGMA` (the Mahalanobis distance of ``(d, w + r)`` under the sum of
        their covariances), the less certain of the distance goes, and the other is current
        if it was. At 10 Hz with 0.05 m of noise a quay's track whose speed was 0.06 m/s
        off drifted 4 sigma from a reading, which started a track; both then followed the
        quay side by side, trading its readings, and the reported track switched 78 times
        in 300 s (now 4). A boat crossing a quay's distance keeps its own track (their rates
        differ), and one just nearer than the quay was in the quay's gate anyway."""
        if len(self.tracks) < 2:
            return
        predicted = [(track, *self._predicted(track, time_s)) for track in self.tracks]
        project = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
        for i, (a, xa, Pa) in enumerate(predicted):
            for b, xb, Pb in predicted[i + 1:]:
                if a not in self.tracks or b not in self.tracks:
                    continue
                gap = project @ (xa - xb)
                spread = project @ (Pa + Pb) @ project.T
                try:
                    squared = float(gap @ np.linalg.solve(spread, gap))
                except np.linalg.LinAlgError:
                    continue
                if not squared <= MERGE_SIGMA ** 2:
                    continue
                keep, drop = (a, b) if Pa[0, 0] <= Pb[0, 0] else (b, a)
                self.tracks.remove(drop)
                if self.current is drop:
                    self.current = keep

    def _surprise(self, track: Track, time_s: float, reading: Reading) -> tuple[float, float]:
        """``(ν, R)``: the reading's normalised innovation against ``track``'s prediction,
        ``ν = (z - d̂) / √(P + R)``, and its variance ``R`` (the track's measured noise
        capping the model's)."""
        x, P = self._predicted(track, time_s)
        variance, _ = self._reading_variance(reading, time_s - track.time_s, track)
        return (reading.distance_m - x[0]) / math.sqrt(P[0, 0] + variance), variance

    def _manoeuvre(self, track: Track, time_s: float, reading: Reading, surprise: float,
                   variance: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The state and covariance the current ``track`` restarts from when ``reading``
        (normalised innovation ``surprise``, variance ``variance``) and the readings before
        it show a manoeuvre (:func:`manoeuvre_readings`), taken by the track or not (a
        stopped vessel's readings soon leave a steady approach's gate): a straight line
        fitted to them, slope ``Σ(t - t̄)(z - z̄) / Σ(t - t̄)²`` of variance
        ``R / Σ(t - t̄)²``, the distance at ``time_s`` of variance
        ``R (1/n + (time_s - t̄)² / Σ(t - t̄)²)``, ``R`` times ``n / n_eff`` where the
        readings come faster than one in :data:`EVIDENCE_STEP_S` (:func:`independent_count`).
        None without one; when the line's speed
        differs from the track's by less than :data:`MANOEUVRE_SPEED_SIGMA` of its own sigma
        under the readings' measured scatter, or by more than
        :attr:`TrackerSettings.manoeuvre_max_mps`; or when the line, taken back to the last
        reading the track took before them, misses it by more than the gate: then the
        readings are of another obstacle (a quay behind a boat that left the band), which
        the gate's rules handle."""
        threshold = self.settings.manoeuvre_sigma
        if not threshold or time_s <= track.time_s:
            return None
        predicted = self._predicted(track, time_s)[0]
        travel_now = track.own_travel_to(time_s, predicted)
        points = [*track.surprises, (time_s, reading.distance_m, surprise, False, travel_now)]
        n = manoeuvre_readings(points, threshold, self.settings.gate_sigma)
        if not n:
            return None
        t = np.array([p[0] for p in points[-n:]])
        # the line is drawn through the distances less the vessel's own travel: its slope
        # is w, the rate the obstacle's own motion gives (the whole rate without own rates)
        z = np.array([p[1] - p[4] for p in points[-n:]])
        fit = FittedLine.through(t, z)
        if fit is None:
            return None
        change = abs(fit.slope - predicted[1])
        # the line's speed against the readings' own scatter where the track measured it
        # (R itself takes twice that, an upper bound for the filter)
        white = track.white_variance(self.settings.min_noise_residuals)
        scatter = variance if white is None else min(variance, white)
        # readings that come faster than one in EVIDENCE_STEP_S say the line no better than
        # n_eff of them would: its variances (check, gate and restart) grow by n / n_eff
        fast = n / independent_count(n, float(t[-1] - t[0]))
        scatter *= fast
        variance *= fast
        if (change > self.settings.manoeuvre_max_mps
                or change < MANOEUVRE_SPEED_SIGMA * math.sqrt(scatter / fit.spread)):
            return None
        taken = ([(p[0], p[1] - p[4]) for p in points[:-n] if p[3]]
                 or [(t_, z_ - s_) for t_, z_, s_ in track.recent if t_ < t[0]])
        if not taken:
            return None
        before_s, before_m = taken[-1]
        at_before, variance_before = fit.at(before_s, variance)
        if abs(at_before - before_m) > self.settings.gate_sigma * math.sqrt(variance + variance_before):
            return None
        state, covariance = fit.state(time_s, variance)
        state[0] += travel_now
        return state, covariance

    def _restart(self, track: Track, time_s: float, reading: Reading,
                 restart: tuple[np.ndarray, np.ndarray]) -> None:
        """The track restarted from :meth:`_manoeuvre`'s line (distance and ``w``), its own
        rate ``r`` as predicted, ``reading`` taken."""
        _, systematic = self._reading_variance(reading, time_s - track.time_s, track)
        x, P, use = track.advance(time_s, self._own)
        track.own_travel_m = track.own_travel_to(time_s, x)
        (distance, w), line_covariance = restart
        track.state = np.array([distance, w, x[2]])
        track.covariance = np.zeros((3, 3))
        track.covariance[:2, :2] = line_covariance
        track.covariance[2, 2] = P[2, 2]
        track.surprises.clear()
        track.drift_sums = [0.0, 0.0]
        track.unconfirmed_line = False
        track.set_own_rate(time_s, self._own, use)
        track.took(time_s, reading, systematic)

    def _two_point_start(self, time_s: float, reading: Reading) -> Track | None:
        """The current track, when seen once, takes a reading beyond its gate if the two
        mean a change of at most :attr:`TrackerSettings.max_speed_mps`: its speed is
        started from the two, ``ḋ = (z₂ - z₁)/Δt`` with ``Var ḋ = (R₁ + R₂)/Δt²`` and
        ``Cov(d, ḋ) = R₂/Δt``. A boat closing at 4 m/s lies 2 m nearer each half second,
        beyond a gate of 3 x 1 m/s x 0.5 s: each reading started a track of its own, and no
        closing speed nor time to contact was ever given. Only the current track: another
        track seen once is an outlier held back, and would make up a speed from a reading
        of something else. None when it does not fit."""
        best = self.current
        if best is None or best.updates != 1 or time_s <= best.time_s:
            return None
        dt = time_s - best.time_s
        if abs(reading.distance_m - best.state[0]) / dt > self.settings.max_speed_mps:
            return None
        first = best.covariance[0, 0]
        variance, systematic = self._reading_variance(reading, dt, best, measured=False)
        x, P, use = best.advance(time_s, self._own)
        best.own_travel_m = best.own_travel_to(time_s, x)
        own_rate, own_variance = x[2], P[2, 2]          # 0 without an own rate
        rate = (reading.distance_m - best.state[0]) / dt
        best.state = np.array([reading.distance_m, rate - own_rate, own_rate])
        best.covariance = np.array([
            [variance, variance / dt, 0.0],
            [variance / dt, (first + variance) / dt ** 2 + own_variance, -own_variance],
            [0.0, -own_variance, own_variance]])
        best.set_own_rate(time_s, self._own, use)
        best.took(time_s, reading, systematic)
        best.unconfirmed_line = True
        return best

    def _line_start(self, time_s: float, reading: Reading) -> Track | None:
        """A new track on a straight line through the current track's readings and a
        reading beyond its gate, while that track is young (2 to
        :data:`LINE_START_READINGS` readings, all kept in ``Track.first``): when the line
        through its readings alone, run on to ``time_s``, meets the reading within the gate,
        and the line through all of them is no faster than
        :attr:`TrackerSettings.max_speed_mps` plus the gate times its sigma, its slope then
        taken at most that speed (readings 0.03 s apart say a speed to 6 m/s, and a line
        through them ran at 25 m/s). The filter's
        speed prior (``initial_speed_sigma_mps``, 1 m/s) suits a quay; a boat closing at
        8 m/s, read ten times a second with 0.3 m of noise, lay beyond the gate every few
        frames, each time starting a track whose prior was again near 0 m/s: in half of 200
        runs no closing speed was shown within 3 s. The young track stays beside the line,
        whose speed is shown once confirmed (:meth:`_still_hypothesis`): a reading that goes
        to another track instead drops the line (one of its readings was a glitch, a young
        quay's readings and a blob read nearer).

        With the ``n`` earlier readings' line of slope ``Σ(t - t̄)(z - z̄) / Σ(t - t̄)²``,
        the reading's gap to it at ``time_s`` has variance
        ``R (1 + 1/n + (time_s - t̄)² / Σ(t - t̄)²)``, ``R`` the reading's; the restart's
        line is fitted to all ``n + 1`` as in :meth:`_manoeuvre`, of the distances less the
        vessel's own travel. None when it does not fit."""
        track = self.current
        if (track is None or not 2 <= track.updates <= LINE_START_READINGS
                or len(track.first) != track.updates or time_s <= track.time_s):
            return None
        s = self.settings
        predicted = self._predicted(track, time_s)[0]
        travel_now = track.own_travel_to(time_s, predicted)
        variance, _ = self._reading_variance(reading, time_s - track.time_s, track,
                                             measured=False)
        t_before = np.array([p[0] for p in track.first])
        z_before = np.array([p[1] - p[2] for p in track.first])
        before = FittedLine.through(t_before, z_before)
        if before is None:
            return None
        at_now, line_variance = before.at(time_s, variance)
        if abs(reading.distance_m - travel_now - at_now) > s.gate_sigma * math.sqrt(
                variance + line_variance):
            return None
        fit = FittedLine.through(np.append(t_before, time_s),
                                 np.append(z_before, reading.distance_m - travel_now))
        if abs(fit.slope) > s.max_speed_mps + s.gate_sigma * math.sqrt(variance / fit.spread):
            return None
        fit = replace(fit, slope=max(-s.max_speed_mps, min(s.max_speed_mps, fit.slope)))
        state, covariance = fit.state(time_s, variance)
        state[0] += travel_now
        line = copy.deepcopy(track)
        line.ident = self._next_id
        self._restart(line, time_s, reading, (state, covariance))
        line.line_readings = [(time_s, reading, reading.distance_m - travel_now)]
        line.line_from = track.ident
        line.rival, line.rival_sum, line.rival_count = None, 0.0, 0   # the young track's own
        self._add(line)
        return line

    def _still_hypothesis(self, line: Track, time_s: float, reading: Reading, x: np.ndarray,
                          variance: float) -> tuple[float, float]:
        """``(ν, S)`` of ``reading`` (variance ``variance``) under a still obstacle where the
        readings since a line start lie, for the first :data:`LINE_CONFIRM_READINGS` after
        it (and :data:`LINE_CONFIRM_SPAN_S`): their mean ``z̄`` of the distances less the
        vessel's own travel (``x``: the line predicted to ``time_s``), ``S = R/m + R +
        (σ_v (t - t̄))²``. The association weighs the reading by the likelier of it and the
        line; the line gives way once the still obstacle is the likelier over all the
        readings since it began (``Track.line_evidence``, the sum of ``ν² + ln S`` as a line
        less that as still: one reading at a time, a fast boat read at 30 Hz lost its
        line to one still-looking reading in the first dozen). A line
        through a young quay's readings 0.1 s apart and a boat lying still 2 m nearer ran at
        10 m/s; the boat's next reading, inside the line's wide gate, confirmed it, and a
        closing speed of 10 m/s and contact in 0.5 s were shown for a boat that did not
        move; and a boat's next reading, far from the line, went to the young quay track,
        which made a speed of 2.5 m/s of the two."""
        since = line.line_readings
        t_mean = sum(t for t, _, _ in since) / len(since)
        still_m = sum(z for _, _, z in since) / len(since) + line.own_travel_to(time_s, x)
        spread = (variance * (1.0 + 1.0 / len(since))
                  + (self.settings.initial_speed_sigma_mps * (time_s - t_mean)) ** 2)
        return (reading.distance_m - still_m) / math.sqrt(spread), spread

    def _as_still(self, line: Track) -> Track:
        """A line start that a reading found likelier as a still obstacle
        (:meth:`_still_hypothesis`): a track of the readings since it alone, in its place
        (same ident; its rival the young track it was drawn from, with the rival test's sums
        over the readings after its first, as :meth:`_rival_if_alike` would have counted
        them: without, a boat's next reading, 1.9 sigma from a young quay track, went to the
        quay's, which made 3 m/s of the two)."""
        since = line.line_readings
        still = self._fresh_track(since[0][0], since[0][1], line.ident)
        rival = next((t for t in self.tracks if t.ident == line.line_from), None)
        still.rival = None if rival is None else rival.ident
        this_own = self._own
        for t, taken, _ in since[1:]:
            self._own = own_rate_of(taken)          # each reading with its own rate
            self._update(still, t, taken)
            if still.rival is not None:
                # the rival test counts the readings since the first as if taken one by one
                x, P = self._predicted(rival, t)
                variance, _ = self._reading_variance(taken, t - rival.time_s, rival, measured=False)
                self._count_against_rival(still, (taken.distance_m - x[0]) / math.sqrt(P[0, 0] + variance))
        self._own = this_own
        self.tracks[self.tracks.index(line)] = still
        if self.current is line:
            self.current = still
        return still

    def _predicted(self, track: Track, time_s: float, with_own: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
        """The track at ``time_s``, with this step's own rate taken (``with_own``; held
        without one)."""
        return track.predicted(time_s, self._own if with_own else None)

    def _takes_over(self, track: Track, time_s: float) -> bool:
        """Whether the track that took this frame's reading becomes the current one."""
        current = self.current
        if current is None or track is current:
            return True
        if (current.unconfirmed_line or current.line_readings is not None) and track.misses_in_row == 0:
            # a speed made from a line that the next reading contradicts: one of its readings
            # was a glitch; do not coast it
            self.tracks.remove(current)
            return True
        if track.state[0] < self._predicted(current, time_s)[0][0]:
            return True                     # never hide a nearer obstacle
        if current.updates == 1 and track.updates > 1 and track.misses_in_row == 0:
            self.tracks.remove(current)     # seen once, contradicted at once: a glitch
            return True
        confirm = self.settings.confirm_frames
        return track.misses_in_row == 0 and current.misses_in_row >= confirm

    def _update(self, track: Track, time_s: float, reading: Reading) -> None:
        if track.recent and track.recent[-1][:2] == (time_s, reading.distance_m):
            # the same frame delivered twice (a feed that repeats): one reading, not two
            # (taken twice, the speed's sigma shrank as if from independent frames: 67 %
            # within 2 sigma on such frames)
            track.misses_in_row = 0
            return
        # a reading a little older than the track's last (a live feed's frames out of order)
        # is taken at the track's own time: its clock never goes back, or the next
        # prediction would cover that stretch twice and bend the closing speed
        time_s = max(time_s, track.time_s)
        x, P, use = track.advance(time_s, self._own)
        dt = time_s - track.time_s
        variance, systematic = self._reading_variance(reading, dt, track)
        innovation = reading.distance_m - x[0]
        track.own_travel_m = track.own_travel_to(time_s, x)
        surprise = innovation / math.sqrt(P[0, 0] + variance)
        track.surprises.append((time_s, reading.distance_m, surprise, True, track.own_travel_m))
        widen = track.drift_alarm(time_s, surprise, self.settings.gate_sigma)
        if widen is not None:
            P[1, 1] += widen
        c = self.settings.robust_sigma
        if c and innovation > 0:                # a farther reading: capped; a nearer one never
            variance = min(self._reading_variance(reading, dt, track, measured=False)[0],
                           max(variance, (innovation / c) ** 2 - P[0, 0]))
        track.unconfirmed_line = False
        gain = P[:, 0] / (P[0, 0] + variance)
        track.state = x + gain * innovation
        track.covariance = P - np.outer(gain, P[0, :])
        track.set_own_rate(time_s, self._own, use)
        track.took(time_s, reading, systematic)

    def _estimate(self, time_s: float, state: str) -> SectionEstimate:
        track = self.current
        if track is None:
            return SectionEstimate(state="none")
        # the own rate of this frame's reading was taken, if the track took it
        x, P = self._predicted(track, time_s, with_own=False)
        # a reading's uncertain time (Reading.time_sigma_s) leaves the distance at the
        # frame's true time uncertain by the rate times it
        timing = timing_variance(x, P, self._time_sigma_s)
        estimate = SectionEstimate(
            distance_m=max(float(x[0]), 0.0),
            sigma_m=math.sqrt(max(P[0, 0], 0.0) + track.systematic_m ** 2 + timing),
            track=track.ident, state=state)
        if track.updates >= self.settings.min_updates and track.line_readings is None:
            # a line start's speed is shown once confirmed (_still_hypothesis); the rate is w and
            # the vessel's own rate r (0 without one)
            rate, rate_variance = distance_rate(x, P)
            estimate.closing_speed_mps = -rate
            estimate.closing_speed_sigma_mps = math.sqrt(rate_variance)
            if estimate.closing_speed_mps > self.settings.min_closing_mps:
                estimate.time_to_contact_s = estimate.distance_m / estimate.closing_speed_mps
        return estimate
