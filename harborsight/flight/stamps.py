"""Frame times coarser than the frames: whole-second stamps at several frames a second.

Frames that share a time lie anywhere within the clock's step, not at one instant; taken as
one instant, a steady 0.4 m/s approach read at 10 Hz with whole-second stamps showed -0.13
to +0.48 m/s. Once two frames in a row share a time, every frame's time is taken as uniform
within the step, one sigma ``step / √12``, the step being the smallest between different
times seen (1 s until one is, and at most 1 s); the tracker allows for it
(:attr:`harborsight.flight.tracker_inputs.Reading.time_sigma_s`). Used by ``run``'s timeline and
by the live engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: the clock's step taken until two different times have been seen, and the most taken (s):
#: a clock to the second (a first step of minutes is a gap in the frames or a bad time)
DEFAULT_STEP_S = 1.0


@dataclass
class StampResolution:
    """What in-order frame times say of their clock's resolution."""

    #: the smallest step between two frames' different times (s)
    step_s: float | None = None
    #: whether two frames in a row had the same time
    shared: bool = False
    _last_s: float | None = None

    def observe(self, frame: int | str, time_s: float) -> tuple[float, str | None]:
        """This frame's time sigma (s), and a note the first time two frames in a row share a
        time. A frame before the last one (out of order) says nothing of the step."""
        note = None
        if self._last_s is not None and time_s >= self._last_s:
            gap = time_s - self._last_s
            if gap > 0:
                self.step_s = gap if self.step_s is None else min(self.step_s, gap)
            elif not self.shared:
                self.shared = True
                note = (f"frame {frame} has the time of the frame before it ({time_s:.3f} s): "
                        "the clock is taken as coarser than the frames, each frame's time as "
                        "anywhere within its step, and the tracker's distances and speeds "
                        "allow for that")
        if self._last_s is None or time_s >= self._last_s:
            self._last_s = time_s
        return self.time_sigma_s, note

    def restart(self) -> None:
        """Forget the last time (it was wrong: a glitch ahead); the next frame's is the last."""
        self._last_s = None

    @property
    def time_sigma_s(self) -> float:
        """One sigma of a frame's time within its step (s); 0 while no two frames shared one."""
        if not self.shared:
            return 0.0
        return min(self.step_s or DEFAULT_STEP_S, DEFAULT_STEP_S) / math.sqrt(12.0)
