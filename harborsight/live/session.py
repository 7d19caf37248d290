"""The live loop: frames from a reader thread, the newest measured, every state published.

The reader (:func:`harborsight.live.stream.replay_video`) puts frames into a one-frame box;
this loop takes the newest, measures it (:class:`~harborsight.live.engine.LiveEngine`) and
hands the state to ``publish`` (the web server's push) and to the recording
(:mod:`harborsight.live.record`: every state, and every measured frame with its metadata as a
flight ``harborsight run`` replays). While no frame comes it re-evaluates the state every
``idle_refresh_s`` so that a stopped source raises its stale alarm on time.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from harborsight.errors import InputError
from harborsight.flight.runner import FlightClock
from harborsight.flight.sources import VideoSource
from harborsight.live.engine import LiveEngine
from harborsight.live.record import SessionRecorder
from harborsight.live.stream import LatestFrame, replay_video


@dataclass
class LiveSummary:
    frames_received: int = 0
    frames_dropped: int = 0
    frames_measured: int = 0
    frames_skipped: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    seconds: float = 0.0
    interrupted: bool = False

    def latency_percentile_ms(self, q: float) -> float | None:
        if not self.latencies_ms:
            return None
        if len(self.latencies_ms) == 1:
            return self.latencies_ms[0]
        return statistics.quantiles(self.latencies_ms, n=100, method="inclusive")[int(q) - 1]


def run_live(source: VideoSource, engine: LiveEngine, *, realtime: bool = True,
             publish: Callable[[dict], None] | None = None, record: Path | None = None,
             stop: threading.Event | None = None, idle_refresh_s: float = 0.2) -> LiveSummary:
    """Run until the source ends or ``stop`` is set (module docstring)."""
    stop = stop or threading.Event()
    box = LatestFrame()

    def arrived(frame, now_s: float) -> None:
        engine.source_arrived("video", now_s)
        if frame.meta is not None:           # a replayed metadata line: both poses at once
            engine.source_arrived("drone", now_s)
            engine.source_arrived("vessel", now_s)

    reader = threading.Thread(target=replay_video, args=(source, box, stop, realtime, arrived),
                              name="harborsight-live-video", daemon=True)
    summary = LiveSummary()
    clock = FlightClock()        # one time base for the trackers, as in `run`
    recorder = SessionRecorder(record) if record is not None else None
    started = time.monotonic()
    reader.start()
    try:
        while not stop.is_set():
            item = box.take(idle_refresh_s)
            if item is None:
                if box.closed:
                    break
                state = engine.refresh()
            elif item.frame.error is not None or item.frame.meta is None:
                summary.frames_skipped += 1
                state = engine.refresh()
            else:
                frame = item.frame
                try:
                    time_s = clock.seconds(frame)
                except InputError:      # off the run's clock: measured, not tracked
                    time_s = None
                state = engine.process(frame.index, frame.image, frame.meta, frame.meta_path,
                                       time_s, item.arrived_s)
                summary.frames_measured += 1
                if state.get("latency_ms") is not None and state.get("frame_index") == frame.index:
                    summary.latencies_ms.append(state["latency_ms"])
                    if recorder is not None:
                        recorder.frame(frame.image, frame.meta, frame.meta_path)
            if publish is not None:
                publish(state)
            if recorder is not None:
                recorder.state(state)
    except KeyboardInterrupt:           # Ctrl-C: stop, and say what was measured
        summary.interrupted = True
    finally:
        stop.set()
        reader.join(timeout=5.0)
        if recorder is not None:
            recorder.close()
        summary.frames_received, summary.frames_dropped = box.received, box.dropped
        summary.seconds = time.monotonic() - started
    return summary
