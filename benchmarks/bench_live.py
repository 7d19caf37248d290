"""The live aid's throughput and latency (issue #28's targets), measured in one run.

The bundled 48-frame berthing flight is scaled to the target resolution (the camera's
intrinsics scaled with it), looped to the wanted duration and written as an H.264-or-MPEG-4
file with its metadata as JSON lines; `harborsight live`'s loop (``run_live``) then replays
it in real time with the default model, and this prints the measured frame rate, the share
of frames dropped, the latency from a frame's arrival to its state (median, p95, max, and
p95 of the first and last quarter: a latency that grows with time shows there), and the
process's resident memory after the first minute and at the end.

    .venv/bin/python benchmarks/bench_live.py [--size 1280x720 --fps 10 --seconds 60]
    .venv/bin/python benchmarks/bench_live.py --size 1920x1080 --fps 30 --seconds 600
    .venv/bin/python benchmarks/bench_live.py --stall-at-s 10 --stall-s 3 --seconds 20
    .venv/bin/python benchmarks/bench_live.py --stream [--size 1280x720 --fps 10]
    .venv/bin/python benchmarks/bench_live.py --websocket [--stream]
    .venv/bin/python benchmarks/bench_live.py --record      # with `live --record`'s writing
    .venv/bin/python benchmarks/bench_live.py --segment-gsd-m 0.12   # with `live --segment-gsd-m`

With ``--websocket`` the states are also pushed by the dashboard's server (Starlette + uvicorn
on 127.0.0.1, as ``--http`` runs it) to a WebSocket client in this process, and the latency
from a frame's arrival to the client's receipt of its state is printed (the issue's measure):
the state's own latency plus the push (publish to receipt, one monotonic clock).

With ``--stream`` the flight goes over the wire instead (its 24 s, the telemetry cannot be
looped): ``live-feed``'s sender encodes the scaled video as H.264 MPEG-TS over UDP on
127.0.0.1 (x264 on the same two cores: a drone would do that part) with the SRT as MAVLink and
the NMEA over UDP; the live loop decodes the stream (PyAV), composes each frame's metadata
from the feeds and measures it, as ``harborsight live --video udp://... --mavlink ... --nmea
...`` does.

With ``--stall-at-s`` the video stops for ``--stall-s`` seconds at that time (the reader
holds its next frame, as a stream that drops out): the time from the last frame before the
stall to the first state with a ``stale_video`` alarm, and from the first frame after it to
the first state without one, are printed against issue #28's 1.5 s and 1 s.

Targets (issue #28, 2 cores): 1280x720 at 10 fps in: at least 10 fps measured, p95 latency at
most 150 ms; 1920x1080 at 30 fps in: frames dropped, p95 at most 250 ms, no growth over 10
minutes (memory within 50 MB of its 1-minute value).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import tempfile
import threading
import time
from pathlib import Path

import cv2

from harborsight.flight import VideoSource
from harborsight.live.engine import LiveEngine
from harborsight.live.session import file_reader, run_live
from harborsight.perception.default_model import load_default_segmenter
from harborsight.perception.gsd_scaling import GsdScaledSegmenter
from harborsight.pipeline import VesselCache
from harborsight.vessel.spec import load_vessel_spec

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"


def write_replay(folder: Path, width: int, height: int, fps: float, seconds: float) -> tuple[Path, Path]:
    """The sample flight at ``width`` x ``height``, looped to ``seconds`` at ``fps``."""
    frames = sorted((SAMPLES / "flight" / "frames").glob("*.json"))
    records, images = [], []
    for path in frames:
        record = json.loads(path.read_text())
        record.pop("vessel_spec", None)
        camera = record["camera"]
        kx, ky = width / camera["width"], height / camera["height"]
        camera.update(width=width, height=height, fx=camera["fx"] * kx, fy=camera["fy"] * ky,
                      cx=(camera["cx"] + 0.5) * kx - 0.5, cy=(camera["cy"] + 0.5) * ky - 0.5)
        records.append(record)
        images.append(cv2.resize(cv2.imread(str(SAMPLES / "flight" / "images" / record["image"])),
                                 (width, height), interpolation=cv2.INTER_CUBIC))
    video, metadata = folder / "replay.mp4", folder / "replay.jsonl"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    n = max(1, round(seconds * fps))
    with metadata.open("w") as out:
        for index in range(n):
            k = index % len(frames)
            record = dict(records[k], frame_index=index)
            record.pop("timestamp", None)           # the loop's time is the video's
            writer.write(images[k])
            out.write(json.dumps(record) + "\n")
    writer.release()
    return video, metadata


class StallingSource:
    """A video source whose frames stop coming for ``stall_s`` at frame ``at_index``."""

    def __init__(self, source: VideoSource, at_index: int, stall_s: float) -> None:
        self.source, self.at_index, self.stall_s = source, at_index, stall_s
        self.fps = source.fps
        self.resumed_s: float | None = None
        self.stalled_s: float | None = None

    def frames(self):
        for frame in self.source.frames():
            if frame.index == self.at_index:
                self.stalled_s = time.monotonic()
                time.sleep(self.stall_s)
                self.resumed_s = time.monotonic()
            yield frame


def stall_delays(events: list[tuple[float, bool]], source: StallingSource, last_before_s: float
                 ) -> tuple[float | None, float | None]:
    """Seconds from the last frame before the stall to the first stale state, and from the
    first frame after it to the first state that is not stale any more."""
    raised = next((t for t, stale in events if stale and t >= last_before_s), None)
    cleared = next((t for t, stale in events if not stale and source.resumed_s is not None
                    and t >= source.resumed_s), None)
    return (None if raised is None else raised - last_before_s,
            None if cleared is None or source.resumed_s is None else cleared - source.resumed_s)


def write_stream_video(folder: Path, width: int, height: int, fps: float) -> Path:
    """The sample flight's 24 s at ``fps`` (each 2 fps frame repeated) and ``width`` x
    ``height``: what a drone's camera would send while the flight's logs were written."""
    images = [cv2.resize(cv2.imread(str(path)), (width, height), interpolation=cv2.INTER_CUBIC)
              for path in sorted((SAMPLES / "flight" / "images").glob("*.jpg"))]
    video = folder / "stream.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    for index in range(int(len(images) / 2.0 * fps)):
        writer.write(images[min(int(index / fps * 2.0), len(images) - 1)])
    writer.release()
    return video


def stream_live(folder: Path, engine: LiveEngine, width: int, height: int, fps: float, publish):
    """Send the flight over UDP and run the live loop on it (module docstring)."""
    import socket

    from harborsight.live.feed import FeedPlan, play_flight
    from harborsight.live.mavlink_in import MavlinkDrone, open_mavlink
    from harborsight.live.nmea_in import NmeaVessel, open_udp, parse_nmea_address, run_nmea
    from harborsight.live.telemetry import FrameComposer, LiveTrack
    from harborsight.live.video_in import read_stream
    from harborsight.telemetry.metadata import camera_block_for

    ports = []
    for _ in range(3):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", 0))
            ports.append(sock.getsockname()[1])
    video = write_stream_video(folder, width, height, fps)
    logs = SAMPLES / "flight" / "logs"
    drone, vessel = LiveTrack("drone", "mavlink"), LiveTrack("vessel", "nmea")
    mavlink = MavlinkDrone(open_mavlink(f"udpin:127.0.0.1:{ports[1]}"), drone,
                           on_position=lambda now: engine.source_arrived("drone", now))
    address = parse_nmea_address(f"udp:127.0.0.1:{ports[2]}")
    sock = open_udp(address)
    nmea = NmeaVessel(vessel, on_fix=lambda now: engine.source_arrived("vessel", now))
    composer = FrameComposer(drone, vessel,
                             camera_for=lambda w, h: camera_block_for("dji-mavic3", w, h, None))
    stop = threading.Event()

    def frames(box, halt, on_arrival):
        read_stream(f"udp://127.0.0.1:{ports[0]}", box, halt, on_arrival)

    def send() -> None:
        time.sleep(1.0)           # the receiver listening first
        play_flight(FeedPlan(video, logs / "flight.SRT", logs / "ship.nmea",
                             video_to=f"udp://127.0.0.1:{ports[0]}",
                             mavlink_to=f"udpout:127.0.0.1:{ports[1]}",
                             nmea_to=f"127.0.0.1:{ports[2]}"))
        time.sleep(1.0)
        stop.set()

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    summary = run_live(frames, engine, composer=composer, publish=publish, stop=stop,
                       feeds=[mavlink.run, lambda halt: run_nmea(address, nmea, halt, sock)])
    sender.join()
    return summary


class WebSocketTimes:
    """The dashboard's server on 127.0.0.1 with a WebSocket client in a thread: for each newly
    measured frame, the state's latency plus the time from its publication to its receipt."""

    def __init__(self, engine: LiveEngine) -> None:
        from websockets.sync.client import connect

        from harborsight.live.server import LiveServer

        self.server = LiveServer(engine.state, "127.0.0.1", 0)
        self.server.start()
        self.published_s: dict[int, float] = {}
        self.totals_ms: list[float] = []
        self.push_ms: list[float] = []
        self._seen: set[int] = set()
        self._socket = connect(f"ws://127.0.0.1:{self.server.port}/ws")
        self._thread = threading.Thread(target=self._receive, daemon=True)
        self._thread.start()
        time.sleep(0.3)                                     # the server registers the client

    def publish(self, state: dict) -> None:
        index = state.get("frame_index")
        if index is not None and index not in self.published_s:
            self.published_s[index] = time.monotonic()
        self.server.publish(state)

    def _receive(self) -> None:
        try:
            for text in self._socket:
                received = time.monotonic()
                state = json.loads(text)
                index = state.get("frame_index")
                if index is None or index in self._seen or index not in self.published_s \
                        or state.get("latency_ms") is None:
                    continue
                self._seen.add(index)
                push = (received - self.published_s[index]) * 1000.0
                self.push_ms.append(push)
                self.totals_ms.append(state["latency_ms"] + push)
        except Exception:            # closed at the end
            return

    def close(self) -> None:
        time.sleep(0.3)
        self._socket.close()
        self.server.stop()


def rss_mb() -> float:
    """Resident memory now (Linux /proc), in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--p95-target-ms", type=float, default=None)
    parser.add_argument("--stall-at-s", type=float, default=None)
    parser.add_argument("--stall-s", type=float, default=3.0)
    parser.add_argument("--stream", action="store_true",
                        help="over UDP: H.264 MPEG-TS video, MAVLink, NMEA (the flight's 24 s)")
    parser.add_argument("--record", action="store_true",
                        help="record the session as `live --record` does (replay only)")
    parser.add_argument("--websocket", action="store_true",
                        help="push the states to a WebSocket client and time their receipt")
    parser.add_argument("--segment-gsd-m", type=float, default=0.0,
                        help="as `live --segment-gsd-m` (0: off, live's default)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    target = args.p95_target_ms or (150.0 if width * height <= 1280 * 720 else 250.0)
    with tempfile.TemporaryDirectory() as tmp:
        video, metadata = write_replay(Path(tmp), width, height, args.fps, args.seconds)
        tug = load_vessel_spec(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml")
        segmenter = load_default_segmenter(None)
        if args.segment_gsd_m:
            segmenter = GsdScaledSegmenter(segmenter, 1, args.segment_gsd_m)
        engine = LiveEngine(segmenter, VesselCache(tug))
        memory = {}
        stop = threading.Event()

        def sample_memory() -> None:
            if not stop.wait(60.0):
                memory["after_60_s"] = rss_mb()

        sampler = threading.Thread(target=sample_memory, daemon=True)
        sampler.start()
        source = VideoSource(video, metadata)
        stalling = None
        if args.stall_at_s is not None:
            stalling = StallingSource(source, round(args.stall_at_s * args.fps), args.stall_s)
            source = stalling
        events: list[tuple[float, bool]] = []
        measured_at: list[float] = []           # when each newly measured frame's state came

        def publish(state: dict) -> None:
            stale = any(a["kind"] == "stale_video" for a in state["alarms"])
            events.append((time.monotonic(), stale))
            if state["frame_index"] is not None and (
                    not measured_at or state["frame_index"] != publish.last_index):
                measured_at.append(time.monotonic())
                publish.last_index = state["frame_index"]
        publish.last_index = None

        pushed = WebSocketTimes(engine) if args.websocket else None

        def deliver(state: dict) -> None:
            publish(state)
            if pushed is not None:
                pushed.publish(state)
        started = time.monotonic()
        if args.stream:
            summary = stream_live(Path(tmp), engine, width, height, args.fps, deliver)
        else:
            summary = run_live(file_reader(source), engine, publish=deliver,
                               record=Path(tmp) / "record" if args.record else None)
        elapsed = time.monotonic() - started
        stop.set()
        if pushed is not None:
            pushed.close()
        memory["end"] = rss_mb()
    latencies = summary.latencies_ms
    quarter = max(1, len(latencies) // 4)

    def p95(values: list[float]) -> float:
        return statistics.quantiles(values, n=100, method="inclusive")[94] if len(values) > 1 else values[0]

    # the rate while frames came (a stream's set-up and tail are not the loop's speed)
    measured_fps = ((len(measured_at) - 1) / (measured_at[-1] - measured_at[0])
                    if len(measured_at) > 1 else summary.frames_measured / elapsed)
    print(f"live {'stream (H.264 MPEG-TS, MAVLink, NMEA over UDP)' if args.stream else 'replay'} "
          f"{width}x{height} at {args.fps:g} fps for {elapsed:.1f} s, default model, this machine")
    print(f"frames in {summary.frames_received}, measured {summary.frames_measured} "
          f"({measured_fps:.1f} fps), dropped {summary.frames_dropped} "
          f"({100 * summary.frames_dropped / max(summary.frames_received, 1):.0f} %)")
    print(f"latency ms: median {statistics.median(latencies):.0f}, p95 {p95(latencies):.0f} "
          f"(target {target:.0f}: {target / p95(latencies):.2f}x), max {max(latencies):.0f}; "
          f"p95 first quarter {p95(latencies[:quarter]):.0f}, last quarter {p95(latencies[-quarter:]):.0f}")
    if pushed is not None and pushed.totals_ms:
        totals, pushes = pushed.totals_ms, pushed.push_ms
        print(f"to a WebSocket client, ms: arrival to receipt median {statistics.median(totals):.0f}, "
              f"p95 {p95(totals):.0f} (target {target:.0f}: {target / p95(totals):.2f}x), max "
              f"{max(totals):.0f}; the push alone median {statistics.median(pushes):.1f}, p95 "
              f"{p95(pushes):.1f}; {len(totals)} measured frames received")
    if "after_60_s" in memory:
        print(f"memory MB: after 60 s {memory['after_60_s']:.0f}, end {memory['end']:.0f} "
              f"(growth {memory['end'] - memory['after_60_s']:+.0f}; target within 50)")
    else:
        print(f"memory MB: end {memory['end']:.0f} (run shorter than 60 s: no growth measured)")
    if width * height <= 1280 * 720:
        print(f"frame rate {measured_fps:.1f} against {args.fps:g} in: {measured_fps / args.fps:.2f}x")
    if stalling is not None and stalling.stalled_s is not None:
        # the reader asks for the stalling frame right after putting the one before it in
        # the box, so the stall begins as the last frame arrives
        raised, cleared = stall_delays(events, stalling, stalling.stalled_s)
        print(f"video stalled {args.stall_s:g} s: stale alarm "
              + ("never raised" if raised is None else f"{raised:.2f} s after the last frame "
                 f"(target 1.5 s: {1.5 / raised:.2f}x)")
              + "; cleared " + ("never" if cleared is None else f"{cleared:.2f} s after the "
                                f"video came back (target 1 s: {1.0 / max(cleared, 1e-3):.1f}x)"))


if __name__ == "__main__":
    main()
