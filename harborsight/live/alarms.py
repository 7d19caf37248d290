"""Per-section alarm states for the live berthing aid: ``ok`` / ``caution`` / ``danger``.

A section's level rises as soon as its distance or its time to contact crosses a threshold,
and falls only once both are clear of the thresholds by a hysteresis margin, so that a
distance hovering at a threshold does not make the display and the sound flicker:

* **danger** when ``d <= danger_m``, or the gap closes with ``ttc <= ttc_s`` while
  ``d <= caution_m`` (fast and already near);
* **caution** when ``d <= caution_m`` or ``ttc <= ttc_s``;
* a level is left only when ``d > threshold + hysteresis_m`` and ``ttc > ttc_s +
  hysteresis_s`` (or the gap is not closing) for every condition that raised it, on
  ``fall_readings`` readings in a row (3 by default): one frame whose mask missed the quay,
  measured clear or far, must not silence a danger for a frame. It then falls to the highest
  level any of those readings holds.

``d`` is the section's conservative distance: the 95 % lower bound ``distance_lower_m`` when
the measurement has one, else the distance. A section measured clear (nothing solid in its
band) is a reading with no distance and falls like any other; a section with no measurement
(out of view, not measured) keeps its level: a vanished reading never clears an alarm. The
live engine also keeps the level of a clear section whose band left the picture short of
the caution distance, and of an ``ok`` one whose bound is where its band left the picture,
short of it, unless the obstacle it saw calls for a level itself
(``harborsight.live.engine``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from harborsight.errors import require_positive

OK, CAUTION, DANGER = "ok", "caution", "danger"
LEVELS = (OK, CAUTION, DANGER)


@dataclass(frozen=True)
class AlarmSettings:
    """Thresholds (metres, seconds) and the margins an alarm must clear to fall."""

    caution_m: float = 5.0
    danger_m: float = 2.0
    ttc_s: float = 30.0
    hysteresis_m: float = 0.5
    hysteresis_s: float = 5.0
    #: a source older than this is stale (issue #28: video 1 s, drone and vessel 2 s)
    video_stale_s: float = 1.0
    telemetry_stale_s: float = 2.0
    #: the vessel's source, where its pose is carried between reports (AIS: 10 s apart, each
    #: carrying the vessel up to 12 s with widened error bars), is stale only after this;
    #: None: ``telemetry_stale_s``
    vessel_stale_s: float | None = None
    #: the distances shown are stale when no frame was measured for this long (frames keep
    #: arriving but cannot be measured: a camera attitude or a heading that stopped)
    measurement_stale_s: float = 2.0
    #: a level falls only on this many readings in a row that let it
    fall_readings: int = 3

    def __post_init__(self) -> None:
        require_positive(self, ("caution_m", "danger_m", "ttc_s", "video_stale_s", "telemetry_stale_s",
                                "measurement_stale_s"))
        if self.vessel_stale_s is not None:
            require_positive(self, ("vessel_stale_s",))
        if not isinstance(self.fall_readings, int) or self.fall_readings < 1:
            raise ValueError(f"fall_readings must be a whole number at least 1, got {self.fall_readings!r}")
        for name in ("hysteresis_m", "hysteresis_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a number at least 0, got {value!r}")
        if self.danger_m >= self.caution_m:
            raise ValueError(f"danger_m ({self.danger_m:g}) must be below caution_m ({self.caution_m:g})")


def _level(distance_m: float | None, ttc_s: float | None, caution_m: float, danger_m: float,
           ttc_limit_s: float) -> int:
    """0 ok, 1 caution, 2 danger for one reading against the given thresholds."""
    near = distance_m is not None and distance_m <= caution_m
    closing_fast = ttc_s is not None and ttc_s <= ttc_limit_s
    if (distance_m is not None and distance_m <= danger_m) or (closing_fast and near):
        return 2
    if near or closing_fast:
        return 1
    return 0


@dataclass
class SectionAlarm:
    """One section's level with hysteresis; ``since`` is when it took its current level."""

    settings: AlarmSettings = field(default_factory=AlarmSettings)
    level: int = 0
    since: float | None = None
    #: readings in a row that let the level fall, and the highest level they hold
    _falling: int = field(default=0, repr=False)
    _falling_to: int = field(default=0, repr=False)

    @property
    def status(self) -> str:
        return LEVELS[self.level]

    def update(self, time_s: float, distance_m: float | None, ttc_s: float | None) -> str:
        """The level after a fresh reading at ``time_s`` (distance, time to contact; either
        may be None when unknown)."""
        s = self.settings
        entering = _level(distance_m, ttc_s, s.caution_m, s.danger_m, s.ttc_s)
        # the level the reading would have with every threshold widened by its margin: the
        # alarm falls only to that
        holding = _level(distance_m, ttc_s, s.caution_m + s.hysteresis_m,
                         s.danger_m + s.hysteresis_m, s.ttc_s + s.hysteresis_s)
        new = self.level
        if entering > self.level:
            new = entering
        elif holding < self.level:
            self._falling_to = holding if self._falling == 0 else max(self._falling_to, holding)
            self._falling += 1
            if self._falling >= s.fall_readings:
                new = self._falling_to
        if new != self.level or holding >= self.level:
            self._falling = 0
        if new != self.level or self.since is None:
            self.level, self.since = new, time_s
        return self.status
