"""One track of a section's tracker (:mod:`harborsight.flight.tracking`, whose docstring
gives the model): its state ``[d, w, r]`` and covariance, the prediction with or without
the vessel's own rate, the readings it keeps to measure its own white noise, the drift test
on ``w``, and the rules on runs of innovations (a manoeuvre) and on readings at video rate."""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from harborsight.flight.tracker_inputs import Reading


@dataclass
class Track:
    ident: int
    time_s: float
    #: ``[d, w, r]``: the distance; its rate less the vessel's own (the whole rate while the
    #: track has no own rate); the vessel's own rate (0 while it has none)
    state: np.ndarray
    covariance: np.ndarray            # 3x3
    updates: int = 1
    misses_in_row: int = 0            # readings in a row that went to another track
    systematic_m: float = 0.0
    #: (sigma_m, sigma_random_m) of the last reading that had them
    last_sigmas: tuple[float, float | None] | None = None
    #: whether ``r`` is in use: the readings gave the vessel's own rate
    has_own: bool = False
    #: white accelerations (m/s², squared) of ``w`` without and with an own rate, and of
    #: ``r``; and the gate (sigma) beyond which an own rate is a change of the vessel's speed
    accel_q: float = 0.0
    obstacle_q: float = 0.0
    own_q: float = 0.0
    own_gate: float = 3.0
    #: the time of the reading whose own rate ``r`` last took
    own_time_s: float = 0.0
    #: the one-sided sums of the drift test on ``w`` (:meth:`drift_alarm`): nearer, farther
    drift_sums: list = field(default_factory=lambda: [0.0, 0.0])
    #: the time of the last reading taken before each sum's run (the run's start)
    drift_starts: list = field(default_factory=lambda: [0.0, 0.0])
    #: ``w`` takes the agile acceleration (``accel_q``) until this time: a drift test fired
    agile_until_s: float = -math.inf
    #: its speed came from two readings alone (two-point start), not yet confirmed by a third
    unconfirmed_line: bool = False
    #: a line start not yet confirmed: ``(time_s, reading, z - own travel)`` of the reading
    #: that started it and of those it took since (the tracker's line-or-still test); None
    #: for any other track
    line_readings: list | None = None
    #: the young track a line start was drawn from
    line_from: int | None = None
    #: the line start's ``Σ (ν² + ln S)`` as a line less that as a still obstacle, over the
    #: readings it took (positive: the still obstacle is the likelier)
    line_evidence: float = 0.0
    #: added to the track's association cost while it has one reading: the alternative a
    #: two-point start leaves (the second reading alone) takes the next reading only
    #: when it is clearly the likelier
    association_penalty: float = 0.0
    #: the track that was current when this one was born of a reading beyond its gate, and
    #: the sum and count of the normalised innovations from it of the readings this one took
    #: since (the tracker's rival test); None: none, or confirmed
    rival: int | None = None
    rival_sum: float = 0.0
    rival_count: int = 0
    #: how far the vessel's own motion has moved the distance since the track began (m), the
    #: filtered ``r`` integrated between readings: ``z - own_travel_m`` is what the obstacle's
    #: own motion and the readings' noise leave
    own_travel_m: float = 0.0
    #: (time_s, distance_m, own_travel_m)
    recent: deque = field(default_factory=lambda: deque(maxlen=3))
    #: the same, of the track's first :data:`LINE_START_READINGS` readings: a young track's
    #: line start draws its line through them
    first: list = field(default_factory=list)
    #: the same, at most one in :data:`NOISE_SPACING_S`: the three-point residuals' readings
    spaced: deque = field(default_factory=lambda: deque(maxlen=3))
    #: |r| of the three-point residuals of the last readings (NaN where three share a time)
    residuals: deque = field(default_factory=deque)
    #: ``(time_s, distance_m, ν, taken, own_travel_m)`` of the readings since the last
    #: manoeuvre (at most :data:`MANOEUVRE_MAX_READINGS`), ``ν = (z - d̂)/√S`` the normalised
    #: innovation; taken: whether the track took the reading (a current track also logs
    #: those it did not)
    surprises: deque = field(default_factory=lambda: deque(maxlen=MANOEUVRE_MAX_READINGS))

    @property
    def own_rate_mps(self) -> float | None:
        """The filtered own rate ``r``, None while the track has none."""
        return float(self.state[2]) if self.has_own else None

    def took(self, time_s: float, reading: Reading, systematic_m: float) -> None:
        """The bookkeeping of a reading taken (its state already updated)."""
        self.time_s = time_s
        self.updates += 1
        self.misses_in_row = 0
        self.systematic_m = systematic_m
        if reading.sigma_m is not None:
            self.last_sigmas = (reading.sigma_m, reading.sigma_random_m)
        self.remember(time_s, reading.distance_m)    # keeps no residual when noise_window is 0

    def remember(self, time_s: float, distance_m: float) -> None:
        """Keep a reading, and the residual of the one before it once three are in a row
        (module docstring), of the distances less the vessel's own travel: one residual a
        reading, so the noise is measured in constant time, without looking back over the
        window. The residuals take readings at least :data:`NOISE_SPACING_S` apart (module
        docstring, "Frame rate")."""
        self.recent.append((time_s, distance_m, self.own_travel_m))
        if len(self.first) < LINE_START_READINGS:
            self.first.append(self.recent[-1])
        if self.spaced and time_s - self.spaced[-1][0] < NOISE_SPACING_S - 1e-9:
            return
        self.spaced.append((time_s, distance_m, self.own_travel_m))
        if len(self.spaced) < 3:
            return
        (t1, z1, s1), (t2, z2, s2), (t3, z3, s3) = self.spaced
        span = t3 - t1
        if span <= 0:
            self.residuals.append(math.nan)
            return
        a = (t3 - t2) / span
        b = 1.0 - a
        self.residuals.append(abs(z2 - s2 - (a * (z1 - s1) + b * (z3 - s3)))
                              / math.sqrt(1.0 + a * a + b * b))

    def white_variance(self, min_residuals: int) -> float | None:
        """The robust variance ``(1.4826 · median |r|)²`` of the readings' white noise from the
        kept residuals (module docstring); None with fewer than ``min_residuals`` of them."""
        kept = [r for r in self.residuals if r == r]           # NaN: three at one time
        if len(kept) < min_residuals:
            return None
        return (1.4826 * statistics.median(kept)) ** 2

    def own_use(self, time_s: float, own: tuple[float, float] | None, x: np.ndarray,
                P: np.ndarray) -> str:
        """How the reading's own rate ``own`` at ``time_s`` is taken by a track predicted to
        ``x, P`` there: ``update`` (a Kalman update of ``r``), ``jump`` (beyond the gate, yet
        a change a vessel can make since ``r`` last took one, at most
        :data:`MAX_OWN_ACCEL_MPS2` plus the gate: a stop, a push), ``ignore`` (beyond that:
        a course read 180° off, a velocity that went wrong; ``r`` is held) or ``none``
        (no own rate, a track without one, or no time since ``r`` took its last: a frame
        delivered twice or late must not count the same velocity again)."""
        if own is None or not self.has_own or time_s <= self.own_time_s:
            return "none"
        rate, sigma = own
        innovation = abs(rate - float(x[2]))
        spread = self.own_gate * math.sqrt(max(float(P[2, 2]), 0.0) + sigma * sigma)
        if innovation <= spread:
            return "update"
        if innovation <= spread + MAX_OWN_ACCEL_MPS2 * (time_s - self.own_time_s):
            return "jump"
        return "ignore"

    def predicted(self, time_s: float, own: tuple[float, float] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance at ``time_s`` with ``own`` taken (:meth:`advance`)."""
        return self.advance(time_s, own)[:2]

    def advance(self, time_s: float, own: tuple[float, float] | None = None
                ) -> tuple[np.ndarray, np.ndarray, str]:
        """State, covariance and what :meth:`own_use` made of ``own`` at ``time_s`` (module
        docstring, "The vessel's own motion"):
        ``F = [[1, Δt, Δt], [0, 1, 0], [0, 0, 1]]`` with white accelerations of ``w`` and
        ``r``; then the reading's ``own = (r, σ)`` as :meth:`own_use` says: a Kalman update
        of ``r``, or a jump, taken whole as a change of the vessel's speed somewhere in the
        interval: ``d`` moves by ``Δr Δt / 2`` with variance ``(Δr Δt)² / 12``, ``r`` forgets
        what it knew, and ``w`` gets :data:`JUMP_W_SHARE` of ``Δr²`` as variance, so that the
        readings arbitrate between a vessel that changed speed and a velocity gone wrong."""
        dt = max(time_s - self.time_s, 0.0)
        F = np.array([[1.0, dt, dt], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        qw = self.obstacle_q if self.has_own and time_s > self.agile_until_s else self.accel_q
        qr = self.own_q if self.has_own else 0.0
        a, b, c = dt ** 3 / 3, dt ** 2 / 2, dt
        Q = np.array([[(qw + qr) * a, qw * b, qr * b], [qw * b, qw * c, 0.0], [qr * b, 0.0, qr * c]])
        x = F @ self.state
        P = F @ self.covariance @ F.T + Q
        use = self.own_use(time_s, own, x, P)
        if use == "update":
            rate, sigma = own
            gain = P[:, 2] / (P[2, 2] + sigma * sigma)
            return x + gain * (rate - x[2]), P - np.outer(gain, P[2, :]), use
        if use == "jump":
            rate, sigma = own
            change = rate - x[2]
            step = change * dt
            x[0] += step / 2.0
            x[2] = rate
            P[0, 0] += step * step / 12.0
            P[1, 1] += JUMP_W_SHARE * change * change
            P[2, :] = 0.0
            P[:, 2] = 0.0
            P[2, 2] = sigma * sigma
        return x, P, use

    def drift_alarm(self, time_s: float, surprise: float, cap: float) -> float | None:
        """The drift test on ``w`` of a track with an own rate (module docstring), at a reading
        taken at ``time_s`` with normalised innovation ``surprise``: Page's one-sided sums,
        nearer ``g⁺ = max(0, g⁺ + (-ν - k) a)`` and farther ``g⁻ = max(0, g⁻ + (ν - k) a)``,
        ``ν`` clipped to ``± cap``, ``k`` = :data:`DRIFT_ALLOWANCE`, each reading weighed by
        ``a = min(1, Δt /`` :data:`EVIDENCE_STEP_S` ``)``, ``Δt`` the time since the track's
        last (module docstring, "Frame rate"). When
        one passes :data:`DRIFT_THRESHOLD`, the obstacle is taken to have changed its speed
        since that sum's run began (``T`` ago): both sums restart, ``w`` takes the agile
        acceleration for :data:`DRIFT_AGILE_S`, and the variance that acceleration would have
        given ``w`` over the run, ``(accel_q - obstacle_q) T``, is returned, to add to the
        prediction's ``P_ww`` (it leaves this reading's update as it was, ``P_dw`` unchanged,
        and lets the next ones move ``w``); None otherwise, and for a track without an own
        rate (its ``w`` is agile already)."""
        if not self.has_own:
            return None
        nu = max(-cap, min(cap, surprise))
        weight = min(1.0, max(time_s - self.time_s, 0.0) / EVIDENCE_STEP_S + 1e-9)
        fired = None
        for k, signed in enumerate((-nu, nu)):     # nearer (ν < 0), farther (ν > 0)
            if self.drift_sums[k] == 0.0:
                self.drift_starts[k] = self.time_s
            self.drift_sums[k] = max(0.0, self.drift_sums[k] + (signed - DRIFT_ALLOWANCE) * weight)
            if self.drift_sums[k] > DRIFT_THRESHOLD:
                fired = self.drift_starts[k]
        if fired is None:
            return None
        self.drift_sums = [0.0, 0.0]
        self.agile_until_s = time_s + DRIFT_AGILE_S
        return (self.accel_q - self.obstacle_q) * max(time_s - fired, 0.0)

    def set_own_rate(self, time_s: float, own: tuple[float, float] | None, use: str) -> None:
        """After a reading at ``time_s`` is taken (``use``: what :meth:`own_use` said of its own
        rate before): a first own rate starts ``r`` at it (``w`` becomes the rate less it,
        ``Var w + σ²``, ``Cov(w, r) = -σ²``); a reading without one holds ``r`` for
        :data:`OWN_HOLD_S` after the last (a velocity missing for a frame at the moment of a
        stop), then makes ``w`` the whole rate again (``w + r``, ``r`` dropped). Either way
        the rate itself carries over, and the drift test starts afresh."""
        if own is None:
            if self.has_own and time_s - self.own_time_s > OWN_HOLD_S:
                T = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
                self.state = T @ self.state
                self.covariance = T @ self.covariance @ T.T
                self.has_own = False
                self.drift_sums = [0.0, 0.0]
        elif not self.has_own:
            rate, sigma = own
            self.state[1] -= rate
            self.state[2] = rate
            variance = sigma * sigma
            self.covariance[1, 1] += variance
            self.covariance[1, 2] = self.covariance[2, 1] = -variance
            self.covariance[0, 2] = self.covariance[2, 0] = 0.0
            self.covariance[2, 2] = variance
            self.has_own = True
            self.own_time_s = time_s
            self.drift_sums = [0.0, 0.0]
        elif use in ("update", "jump"):
            self.own_time_s = time_s

    def own_travel_to(self, time_s: float, x: np.ndarray) -> float:
        """The own travel at ``time_s`` with ``x`` the state predicted there: the mean of the
        filtered ``r`` at either end times the interval (none without an own rate)."""
        if not self.has_own:
            return self.own_travel_m
        dt = max(time_s - self.time_s, 0.0)
        return self.own_travel_m + 0.5 * (float(self.state[2]) + float(x[2])) * dt


#: a young track (at most this many readings) whose readings and a reading beyond its gate
#: lie on one line may restart from it (the tracker's line start)
LINE_START_READINGS = 5
#: a line start's speed is shown once it has taken this many readings after the one that
#: started it, spanning this long (s) with it, each likelier from the line than from a still
#: obstacle
LINE_CONFIRM_READINGS = 2
LINE_CONFIRM_SPAN_S = 0.4
#: a manoeuvre is looked for over the readings of the last this many seconds, and the line
#: that restarts a track spans at least the shorter time (a line through readings 0.2 s
#: apart at 10 Hz says little of a speed)
MANOEUVRE_WINDOW_S = 1.0
MANOEUVRE_MIN_SPAN_S = 0.4
MANOEUVRE_MAX_READINGS = 64
#: the largest change of a vessel's own rate (m/s a second, beyond the gate) taken as real:
#: a tug stops from 0.5 m/s in 2-3 s; 2 m/s in half a second (a course read 180° off) is not
MAX_OWN_ACCEL_MPS2 = 1.0
#: the share of a jump of the own rate, squared, given to the variance of ``w``
JUMP_W_SHARE = 0.1
#: how long (s) a track holds its own rate through readings without one before it makes the
#: whole rate ``w`` again
OWN_HOLD_S = 2.0
#: the least one-sigma (m/s) of an own rate (a stated 0 would make the filter blind to the image)
MIN_OWN_RATE_SIGMA_MPS = 0.01
#: the drift test on ``w`` (:meth:`Track.drift_alarm`): Page's sums of normalised
#: innovations, less this allowance a reading (readings less than EVIDENCE_STEP_S apart count
#: in proportion), fire beyond the threshold, and ``w`` is then agile for that long (s)
DRIFT_ALLOWANCE = 0.5
DRIFT_THRESHOLD = 6.0
DRIFT_AGILE_S = 3.0
#: readings closer together than this (s) are worth less than one independent look each to
#: the tests on runs of innovations (the manoeuvre rule, the drift test): a mask's error
#: repeats from one video frame to the next (module docstring, "Frame rate")
EVIDENCE_STEP_S = 0.5
#: the three-point noise residuals take readings at least this far apart (s): all of them at
#: 2 Hz with up to 0.05 s of jitter, every fifth at 10 Hz
NOISE_SPACING_S = 0.9 * EVIDENCE_STEP_S
#: the line restarts a track only when its speed differs from the track's by this many of
#: its own sigmas, under the readings' measured scatter (a line through readings that
#: scatter by 0.3 m over a second says the speed to 0.4 m/s: on a steady approach, two such
#: restarts in 600 s cost the closing speed a third of its accuracy)
MANOEUVRE_SPEED_SIGMA = 2.5


def manoeuvre_readings(surprises: list[tuple], threshold: float, cap: float = math.inf) -> int:
    """How many of the last readings ``(time_s, distance_m, ν, ...)`` (the newest last) a
    manoeuvre spans: the most ``n >= 2`` of them, spanning :data:`MANOEUVRE_MIN_SPAN_S` to
    :data:`MANOEUVRE_WINDOW_S`, that lie on one side of their predictions with
    ``|Σν| / √n > threshold``, each ``ν`` clipped to ``± cap`` (under the filter's model
    ``Σν/√n`` is a standard normal: beyond 3.25, once in 1,700 draws a side; clipped, one outlier
    far out does not make a manoeuvre of the reading after it); readings faster than one in
    :data:`EVIDENCE_STEP_S` count as :func:`independent_count` says, the mean ``ν`` times
    the square root of that; 0 when none do. The most,
    so that the line a track restarts from is drawn through as many readings as the
    manoeuvre gives."""
    if len(surprises) < 2:
        return 0
    newest, side = surprises[-1][0], math.copysign(1.0, surprises[-1][2])
    run = 0                     # the readings in the window on the newest one's side
    for t, _, v, *_ in reversed(surprises):
        if newest - t > MANOEUVRE_WINDOW_S or v * side <= 0:
            break
        run += 1
    for n in range(run, 1, -1):
        last = surprises[-n:]
        span_s = newest - last[0][0]
        if (span_s >= MANOEUVRE_MIN_SPAN_S
                and abs(sum(max(-cap, min(cap, p[2])) for p in last)) / n
                * math.sqrt(independent_count(n, span_s)) > threshold):
            return n
    return 0


@dataclass(frozen=True)
class FittedLine:
    """The least-squares line through ``n`` readings ``(t, z)``: slope
    ``Σ(t - t̄)(z - z̄) / Σ(t - t̄)²`` (``spread`` the denominator), which the manoeuvre rule and
    the line start restart a track from. With a reading's variance ``R``, the line's
    distance at ``s`` has variance ``R (1/n + (s - t̄)² / spread)``, its slope ``R / spread``
    and the two a covariance of ``R (s - t̄) / spread``."""

    t_mean: float
    z_mean: float
    slope: float
    spread: float
    n: int

    @classmethod
    def through(cls, t: np.ndarray, z: np.ndarray) -> FittedLine | None:
        """The line through the readings, None when their times do not spread."""
        t_mean = float(t.mean())
        spread = float(np.sum((t - t_mean) ** 2))
        if spread <= 0:
            return None
        return cls(t_mean, float(z.mean()), float(np.sum((t - t_mean) * (z - z.mean()))) / spread,
                   spread, len(t))

    def at(self, at_s: float, variance: float) -> tuple[float, float]:
        """The line's distance at ``at_s`` and its variance."""
        lead = at_s - self.t_mean
        return self.z_mean + self.slope * lead, variance * (1.0 / self.n + lead ** 2 / self.spread)

    def state(self, at_s: float, variance: float) -> tuple[np.ndarray, np.ndarray]:
        """``[distance, slope]`` at ``at_s`` and their covariance."""
        distance, distance_variance = self.at(at_s, variance)
        lead = at_s - self.t_mean
        return (np.array([distance, self.slope]),
                np.array([[distance_variance, variance * lead / self.spread],
                          [variance * lead / self.spread, variance / self.spread]]))


def independent_count(n: int, span_s: float) -> float:
    """What ``n`` readings spanning ``span_s`` are worth to a test that takes them as
    independent: ``n``, or ``1 + span_s / EVIDENCE_STEP_S`` when they come faster than one in
    :data:`EVIDENCE_STEP_S` (module docstring, "Frame rate")."""
    return min(float(n), 1.0 + span_s / EVIDENCE_STEP_S + 1e-9)
