"""What the per-section tracker (:mod:`harborsight.flight.tracking`) takes and gives: its
settings, a frame's reading of a section and the estimate it returns, the checks that make a
reading safe to filter, and the small sums on a track's state that the tracker, its tracks
and the run's timeline share (the distance's whole rate, a time's share of the variance)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harborsight.errors import require_positive
from harborsight.flight.track import MIN_OWN_RATE_SIGMA_MPS


@dataclass(frozen=True)
class TrackerSettings:
    accel_sigma_mps2: float = 0.05
    gate_sigma: float = 3.0
    confirm_frames: int = 3
    max_coast_s: float = 5.0
    initial_speed_sigma_mps: float = 1.0
    min_updates: int = 3
    min_closing_mps: float = 0.05
    drift_time_s: float = 60.0
    #: the least one-sigma of a reading (m), when its own sigma is tiny
    min_reading_sigma_m: float = 0.02
    #: the one-sigma taken for a reading without one when no track says better (m)
    unknown_reading_sigma_m: float = 0.5
    #: the fastest a section's obstacle closes or opens (m/s): a track seen once takes a
    #: reading beyond its gate when the two mean no faster a change (two-point start)
    max_speed_mps: float = 10.0
    max_tracks: int = 3
    #: readings a track keeps to measure its own white noise (module docstring); 0: off
    noise_window: int = 15
    min_noise_residuals: int = 5
    #: the measured white sigma is used times this (an upper bound of a noisy estimate)
    noise_margin: float = 2.0
    #: a farther reading's innovation is capped at this many sigma; 0: off
    robust_sigma: float = 3.0
    #: readings on one side of the prediction whose summed normalised innovations exceed
    #: this many sigma are a manoeuvre (a stop, a push): the track restarts from a line
    #: through them (module docstring); 0: off
    manoeuvre_sigma: float = 3.25
    #: the most a manoeuvre changes a section's closing speed (m/s)
    manoeuvre_max_mps: float = 1.5
    #: white acceleration (m/s²) of what is left of a distance's rate once the vessel's own
    #: motion is taken out (readings with ``own_rate_mps``: module docstring, "The vessel's
    #: own motion"): the obstacle's own motion, none for a quay; ``accel_sigma_mps2`` covers
    #: the vessel's and the obstacle's together where no own rate is given
    obstacle_accel_sigma_mps2: float = 0.01

    def __post_init__(self) -> None:
        require_positive(self, ("accel_sigma_mps2", "obstacle_accel_sigma_mps2",
                                "gate_sigma", "max_coast_s",
                                "initial_speed_sigma_mps", "drift_time_s", "min_reading_sigma_m",
                                "unknown_reading_sigma_m", "max_speed_mps", "manoeuvre_max_mps"))
        for name in ("confirm_frames", "min_updates", "max_tracks"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        for name in ("robust_sigma", "manoeuvre_sigma"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be 0 (off) or positive, got {getattr(self, name)}")
        if not (self.min_closing_mps >= 0 and math.isfinite(self.min_closing_mps)):
            # below 0 an opening gap got a (negative) time to contact; NaN turned it off
            raise ValueError(f"min_closing_mps must be finite and at least 0, got {self.min_closing_mps}")
        if not self.noise_margin >= 1:
            raise ValueError(f"noise_margin must be at least 1, got {self.noise_margin}")
        if self.min_noise_residuals < 1:
            raise ValueError(f"min_noise_residuals must be at least 1, got {self.min_noise_residuals}")
        if self.noise_window and self.noise_window < self.min_noise_residuals + 2:
            raise ValueError(f"noise_window must be 0 (off) or at least min_noise_residuals + 2 "
                             f"= {self.min_noise_residuals + 2}, got {self.noise_window}")


@dataclass
class Reading:
    """One frame's clearance of one section: distance and its sigma (total and random part),
    and the rate (m/s, negative closing) at which the vessel's own motion changes it were the
    obstacle fixed, with its sigma, when the frame gives the vessel's velocity
    (:func:`harborsight.clearance.own_motion.add_own_rates`)."""

    distance_m: float
    sigma_m: float | None = None
    sigma_random_m: float | None = None
    own_rate_mps: float | None = None
    own_rate_sigma_mps: float | None = None
    #: how uncertain the frame's time is against the other frames' (s, one sigma): frames
    #: stamped to the whole second at several a second lie anywhere in their second
    time_sigma_s: float = 0.0




#: the estimate's states of a section that had a reading this frame (else it coasts a
#: prediction, or has nothing)
MEASURED_STATES = ("updated", "new", "held")


#: a reading's sigma is taken as at most this (m): one that says more says it knows nothing
#: of the distance, and its square would overflow the filter's arithmetic (1e155)
MAX_READING_SIGMA_M = 1e3
#: a reading's time is taken as uncertain by at most this (s)
MAX_TIME_SIGMA_S = 60.0
#: an own rate whose sigma is more than this (m/s) is no own rate: it says nothing of the
#: vessel's motion, and at 7e5 it took the distance's sigma to 0 by cancellation
MAX_OWN_RATE_SIGMA_MPS = 100.0


def sane_reading(reading: Reading) -> Reading | None:
    """The reading with a sigma that is not a finite non-negative number taken as not given,
    and one above :data:`MAX_READING_SIGMA_M` as that; an own rate only with a finite sigma of
    at most :data:`MAX_OWN_RATE_SIGMA_MPS`; None for a distance that is not finite (nothing
    to go on: as a frame without one)."""
    if not math.isfinite(reading.distance_m):
        return None

    def usable(sigma: float | None) -> float | None:
        if sigma is None or not math.isfinite(sigma) or sigma < 0:
            return None
        return min(sigma, MAX_READING_SIGMA_M)

    rate, rate_sigma = reading.own_rate_mps, usable(reading.own_rate_sigma_mps)
    if (rate is None or not math.isfinite(rate) or rate_sigma is None
            or rate_sigma > MAX_OWN_RATE_SIGMA_MPS):
        rate, rate_sigma = None, None         # an own rate needs both, finite
    time_sigma = reading.time_sigma_s if math.isfinite(reading.time_sigma_s) else 0.0
    return Reading(reading.distance_m, usable(reading.sigma_m), usable(reading.sigma_random_m),
                   rate, rate_sigma, min(max(time_sigma, 0.0), MAX_TIME_SIGMA_S))


def distance_rate(x: np.ndarray, P: np.ndarray) -> tuple[float, float]:
    """The distance's whole rate ``ḋ = w + r`` of a state ``x = [d, w, r]`` and its variance
    ``P_ww + P_rr + 2 P_wr``."""
    return float(x[1] + x[2]), max(float(P[1, 1] + P[2, 2] + 2.0 * P[1, 2]), 0.0)


def timing_variance(x: np.ndarray, P: np.ndarray, time_sigma_s: float) -> float:
    """What a time known to ``σ_t`` adds to a distance's variance: ``(ḋ² + P_ḋḋ) σ_t²``."""
    if time_sigma_s <= 0:
        return 0.0
    rate, rate_variance = distance_rate(x, P)
    return (rate * rate + rate_variance) * time_sigma_s ** 2


def own_rate_of(reading: Reading | None) -> tuple[float, float] | None:
    """A (sane) reading's own rate and its sigma, or None."""
    if reading is None or reading.own_rate_mps is None or reading.own_rate_sigma_mps is None:
        return None
    return reading.own_rate_mps, max(reading.own_rate_sigma_mps, MIN_OWN_RATE_SIGMA_MPS)


def seen_clear(section) -> tuple[float, float] | None:
    """What a section measured ``clear`` saw of its band, for :meth:`SectionTracker.step`:
    ``(hidden_to_m or 0, clear_to_m)``, its water seen from where the vessel stops hiding
    it out to where the band leaves the picture (no end when it does not); None for any
    other section, or a clear one seen nowhere (hidden in full, or a pose the image
    contradicts)."""
    if section.status != "clear" or section.clear_to_m == 0.0:
        return None
    near_m = section.hidden_to_m or 0.0
    far_m = math.inf if section.clear_to_m is None else section.clear_to_m   # no edge in view
    return (near_m, far_m) if far_m > near_m else None


@dataclass
class SectionEstimate:
    """What the tracker says of one section after a frame."""

    distance_m: float | None = None
    sigma_m: float | None = None
    closing_speed_mps: float | None = None
    closing_speed_sigma_mps: float | None = None
    time_to_contact_s: float | None = None
    track: int | None = None
    state: str = "none"       # updated | new | held | coasting | clear | none
