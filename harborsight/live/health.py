"""Health of the live inputs: how old the newest video frame, drone pose and vessel pose are,
and at what rate each arrives. Times are the process's monotonic clock in seconds."""

from __future__ import annotations

from dataclasses import dataclass, field

#: weight of the newest interval in the rate's running mean
_RATE_WEIGHT = 0.2


@dataclass
class SourceHealth:
    """Arrivals of one source: age of the newest and an exponential mean of the rate."""

    name: str
    stale_after_s: float
    last_s: float | None = None
    interval_s: float | None = None
    count: int = 0
    _stale_since: float | None = field(default=None, repr=False)

    def arrived(self, now_s: float) -> None:
        if self.last_s is not None and now_s > self.last_s:
            gap = now_s - self.last_s
            self.interval_s = gap if self.interval_s is None else (
                (1 - _RATE_WEIGHT) * self.interval_s + _RATE_WEIGHT * gap)
        self.last_s = now_s
        self.count += 1

    def age_s(self, now_s: float) -> float | None:
        return None if self.last_s is None else max(0.0, now_s - self.last_s)

    def stale(self, now_s: float) -> bool:
        """Never arrived, or older than ``stale_after_s``."""
        age = self.age_s(now_s)
        return age is None or age > self.stale_after_s

    def stale_since(self, now_s: float) -> float | None:
        """When the source went stale (the moment its age passed the limit), or None."""
        if not self.stale(now_s):
            self._stale_since = None
            return None
        if self._stale_since is None:
            self._stale_since = now_s if self.last_s is None else self.last_s + self.stale_after_s
        return self._stale_since

    def to_dict(self, now_s: float) -> dict:
        age = self.age_s(now_s)
        rate = None if not self.interval_s else 1.0 / self.interval_s
        return {"age_s": None if age is None else round(age, 3),
                "rate_hz": None if rate is None else round(rate, 2),
                "stale": self.stale(now_s), "count": self.count}
