"""The live loop: frames from a reader thread, the newest measured, every state published.

The reader (:func:`harborsight.live.stream.replay_video` for a recorded flight,
:func:`harborsight.live.video_in.read_stream` for a live stream) puts frames into a
one-frame box; the telemetry feeds (MAVLink, NMEA) run in threads of their own. This loop
takes the newest frame, gives it its metadata (its own, replayed; or composed from the live
feeds at its time by :class:`~harborsight.live.telemetry.FrameComposer`), measures it
(:class:`~harborsight.live.engine.LiveEngine`) and
hands the state to ``publish`` (the web server's push) and to the recording
(:mod:`harborsight.live.record`: every state; every measured frame with its metadata as a
flight ``harborsight run`` replays; and what ``run`` writes: reports, sections.csv, the
annotated video, run.json). While no frame comes it re-evaluates the state every
``idle_refresh_s`` so that a stopped source raises its stale alarm on time.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from harborsight.errors import InputError
from harborsight.flight.runner import FlightClock
from harborsight.flight.sources import FlightFrame, VideoSource
from harborsight.frame import FrameMetadata, parse_frame_metadata
from harborsight.live.engine import LiveEngine
from harborsight.live.record import SessionRecorder
from harborsight.live.stream import LatestFrame, VideoFrames, replay_video
from harborsight.live.telemetry import FrameComposer


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


#: a frame reader: fills the box until the stream ends or ``stop`` is set, calling
#: ``on_arrival(frame, now_s)`` for each frame, and closes the box
FrameReader = Callable[[LatestFrame, threading.Event, Callable[[FlightFrame, float], None]], None]


def file_reader(source: VideoSource | VideoFrames, realtime: bool = True) -> FrameReader:
    """A recorded flight (video + metadata lines), or a video alone, as a frame reader."""
    return lambda box, stop, on_arrival: replay_video(source, box, stop, realtime, on_arrival)


def run_live(frames: FrameReader, engine: LiveEngine, *, composer: FrameComposer | None = None,
             feeds: Iterable[Callable[[threading.Event], None]] = (),
             publish: Callable[[dict], None] | None = None, record: Path | None = None,
             stop: threading.Event | None = None, idle_refresh_s: float = 0.2,
             record_inputs: dict | None = None) -> LiveSummary:
    """Run until the frames end or ``stop`` is set (module docstring). ``feeds``: thread
    bodies of the telemetry readers, run with the same ``stop``."""
    stop = stop or threading.Event()
    box = LatestFrame()

    def arrived(frame, now_s: float) -> None:
        engine.source_arrived("video", now_s)
        if frame.meta is not None:           # a replayed metadata line: both poses at once
            engine.source_arrived("drone", now_s)
            engine.source_arrived("vessel", now_s)

    threads = [threading.Thread(target=frames, args=(box, stop, arrived),
                                name="harborsight-live-video", daemon=True)]
    threads += [threading.Thread(target=feed, args=(stop,), name=f"harborsight-live-feed-{k}",
                                 daemon=True) for k, feed in enumerate(feeds)]
    summary = LiveSummary()
    clock = FlightClock()        # one time base for the trackers, as in `run`
    recorder = None
    if record is not None:
        alarms = engine.alarm_settings
        recorder = SessionRecorder(record, inputs=record_inputs, settings={
            "method": engine.clearance.method, "pose_margin_px": engine.clearance.pose_margin_px,
            "own_rim_px": engine.clearance.own_rim_px,
            "sigma_options": dict(engine.clearance.sigma_options),
            "model": str(engine.segmenter.path) if engine.segmenter is not None else None,
            "caution_m": alarms.caution_m, "danger_m": alarms.danger_m, "ttc_s": alarms.ttc_s},
            caution_m=alarms.caution_m, danger_m=alarms.danger_m)
    started = time.monotonic()
    for thread in threads:
        thread.start()
    try:
        while not stop.is_set():
            item = box.take(idle_refresh_s)
            if item is None:
                if box.closed:
                    break
                state = engine.refresh()
            else:
                frame = item.frame
                if frame.meta is None and frame.error is None and composer is not None:
                    frame.meta, frame.error = _composed(composer, frame, item.arrived_s)
                measured = frame.error is None and frame.meta is not None
                if not measured:
                    summary.frames_skipped += 1
                    # a bad frame is reported; a video frame without a metadata line is not
                    # (telemetry is often slower than the camera)
                    state = (engine.frame_failed(frame.index, frame.error) if frame.error
                             else engine.refresh())
                else:
                    state = _measure(engine, clock, frame, item.arrived_s, summary, recorder)
            if publish is not None:
                publish(state)
            if recorder is not None:
                recorder.state(state)
    except KeyboardInterrupt:           # Ctrl-C: stop, and say what was measured
        summary.interrupted = True
    finally:
        stop.set()
        for thread in threads:
            thread.join(timeout=5.0)
        if recorder is not None:
            recorder.close()
        summary.frames_received, summary.frames_dropped = box.received, box.dropped
        summary.seconds = time.monotonic() - started
    return summary


def _measure(engine: LiveEngine, clock: FlightClock, frame: FlightFrame, arrived_s: float,
             summary: LiveSummary, recorder: SessionRecorder | None) -> dict:
    try:
        time_s = clock.seconds(frame)
    except InputError:      # off the run's clock: measured, not tracked
        time_s = None
    state = engine.process(frame.index, frame.image, frame.meta, frame.meta_path, time_s, arrived_s,
                           no_data=frame.no_data)
    summary.frames_measured += 1
    if state.get("latency_ms") is not None and state.get("frame_index") == frame.index:
        summary.latencies_ms.append(state["latency_ms"])
        if recorder is not None:
            recorder.frame(frame.image, frame.meta, frame.meta_path,
                           engine.report_of(frame.index), time_s)
    return state


def _composed(composer: FrameComposer, frame: FlightFrame, arrived_s: float
              ) -> tuple[FrameMetadata | None, str | None]:
    """The frame's metadata from the live feeds, or why there is none."""
    height, width = frame.image.shape[:2]
    record, why = composer.compose(frame.index, arrived_s, width, height)
    if record is None:
        return None, f"frame {frame.index} not measured: {why}"
    try:
        return parse_frame_metadata(record, frame.source), None
    except InputError as exc:
        return None, f"frame {frame.index} not measured: {exc}"
