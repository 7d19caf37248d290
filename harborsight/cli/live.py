"""``harborsight live``: the berthing aid while the ship berths (a thin shell over
:mod:`harborsight.live`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from harborsight.cli.app import (
    OWN_MOTION_HELP,
    OWN_RIM_PX,
    POSE_MARGIN_PX,
    REFINE_POSE_HELP,
    SEGMENT_GSD_HELP,
    SIGMA_HELP,
    Method,
    app,
    clearance_settings,
    console,
    err_console,
    load_segmenter,
    vessel_cache,
)
from harborsight.errors import HarborsightError, InputError


def _host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not host or not 0 <= number <= 65535:
        raise InputError(None, "--http", f"expected HOST:PORT (e.g. 127.0.0.1:8080), got {text!r}")
    return host, number


def _feeds_setup(engine, *, mavlink: str, mavlink_altitude: str, nmea: str | None,
                 signalk: str | None, signalk_token: str | None, ais: str | None,
                 mmsi: int | None, allow_cog_heading: bool, camera: str,
                 water_level_m: float, mount: str, camera_pitch_deg: float,
                 camera_yaw_deg: float | None, video_delay_s: float, drone_offset_s: float,
                 vessel_offset_s: float, hold_s: float):
    """The live telemetry readers (opened here, so that a bad address ends the command with
    its option named) and the composer of the frames' metadata."""
    from harborsight.live.ais_in import AisVessel
    from harborsight.live.mavlink_in import MavlinkDrone, open_mavlink
    from harborsight.live.nmea_in import NmeaVessel, open_udp, parse_nmea_address, run_nmea
    from harborsight.live.signalk import SignalKVessel, stream_url
    from harborsight.live.telemetry import FrameComposer, LiveTrack
    from harborsight.sim.cameras import CAMERA_PRESETS
    from harborsight.telemetry.metadata import MOUNTS, CameraMount, camera_block_for

    if mount not in MOUNTS:
        raise InputError(None, "--mount", f"{mount!r}: expected one of {', '.join(MOUNTS)}")
    if camera not in CAMERA_PRESETS:
        camera_block_for(camera, None, None, None)       # a missing or bad file: say so now
    address = (parse_nmea_address(nmea) if nmea is not None else
               parse_nmea_address(ais, "--ais") if ais is not None else None)
    signalk_url = stream_url(signalk, "--signalk") if signalk is not None else None
    drone = LiveTrack(f"mavlink {mavlink}", "mavlink",
                      alt_reference=("height above the home point (GLOBAL_POSITION_INT.relative_alt)"
                                     if mavlink_altitude == "relative" else
                                     "above mean sea level (GLOBAL_POSITION_INT.alt)"))
    vessel = (LiveTrack(f"{'nmea' if nmea else 'ais'} {address}", "nmea" if nmea else "ais")
              if address is not None
              else LiveTrack(f"signalk {signalk_url}", "signalk"))
    drone.clock.offset_s, vessel.clock.offset_s = drone_offset_s, vessel_offset_s
    for track, name in ((drone, "drone"), (vessel, "vessel")):
        track.on_warning = lambda source, message, name=name: engine.warn(name, message)
    reader = MavlinkDrone(open_mavlink(mavlink), drone, altitude=mavlink_altitude,
                          on_position=lambda now: engine.source_arrived("drone", now))
    on_fix = lambda now: engine.source_arrived("vessel", now)      # noqa: E731
    if address is not None:
        listener = (NmeaVessel(vessel, on_fix=on_fix) if nmea is not None else
                    AisVessel(vessel, mmsi, allow_cog_heading=allow_cog_heading, on_fix=on_fix))
        # a port in use: say so now
        sock = open_udp(address, "--nmea" if nmea else "--ais") if address.kind == "udp" else None

        def vessel_feed(stop):
            run_nmea(address, listener, stop, sock)
    else:
        vessel_feed = SignalKVessel(signalk_url, vessel, token=signalk_token, on_fix=on_fix).run
    composer = FrameComposer(
        drone, vessel, camera_for=lambda width, height: camera_block_for(camera, width, height, camera),
        water_level_m=water_level_m, mount=CameraMount(mount, camera_pitch_deg, camera_yaw_deg),
        video_delay_s=video_delay_s, hold_s=hold_s)
    return [reader.run, vessel_feed], composer


@app.command("live")
def live_command(
    video: Annotated[str, typer.Option(
        help="The drone's video: a file (with --realtime it plays at its own frame rate, as a "
        "stream would arrive), or a stream: rtsp://, rtmp://, srt://, udp:// (MPEG-TS), "
        "http(s):// or a capture device (/dev/video0). A stream that drops is reopened.")],
    rtsp_transport: Annotated[str, typer.Option(
        help="An rtsp:// video: tcp (RTP inside the RTSP connection; survives a lossy link "
        "and NAT) or udp (for servers without TCP).")] = "tcp",
    metadata: Annotated[Path | None, typer.Option(
        help="A file's telemetry: JSON lines, one harborsight.frame/1 object per video frame "
        "(drone and vessel poses), replayed on the video's clock. Without it: --mavlink and "
        "--nmea.")] = None,
    mavlink: Annotated[str | None, typer.Option(
        help="The drone's live MAVLink (pymavlink address, e.g. udpin:0.0.0.0:14550, "
        "tcp:HOST:PORT, /dev/ttyACM0): GLOBAL_POSITION_INT, GPS_RAW_INT, ATTITUDE, "
        "GIMBAL_DEVICE_ATTITUDE_STATUS or MOUNT_STATUS, SYSTEM_TIME.")] = None,
    mavlink_altitude: Annotated[str, typer.Option(
        help="relative: GLOBAL_POSITION_INT.relative_alt (above home; give --water-level-m in "
        "that datum), or amsl: .alt.")] = "relative",
    nmea: Annotated[str | None, typer.Option(
        help="The vessel's live NMEA 0183: udp:PORT, udp:HOST:PORT, tcp:HOST:PORT or a serial "
        "device /dev/ttyUSB0[@BAUD] (RMC/GGA position, HDT/THS/HDG/HDM heading).")] = None,
    signalk: Annotated[str | None, typer.Option(
        help="The vessel from a Signal K server instead of --nmea: ws://HOST:3000 "
        "(navigation.position, navigation.headingTrue of the self vessel).")] = None,
    ais: Annotated[str | None, typer.Option(
        help="The vessel from its AIS transponder instead of --nmea: udp:PORT, tcp:HOST:PORT "
        "or a serial device (AIVDO, or --mmsi's AIVDM position reports).")] = None,
    mmsi: Annotated[int | None, typer.Option(
        min=1, max=999_999_999, help="With --ais: the vessel (default: its own AIVDO).")] = None,
    allow_cog_heading: Annotated[bool, typer.Option(
        help="With --ais: a report without a true heading takes its course over ground "
        "(wrong wherever the vessel moves sideways).")] = False,
    signalk_out: Annotated[str | None, typer.Option(
        help="Publish to a Signal K server, ws://HOST:3000: notifications.harborsight.* "
        "(normal / warn / alarm per section, alert while data is stale) and the clearances "
        "(harborsight.clearance.*), for chart plotters and MFDs.")] = None,
    signalk_token: Annotated[str | None, typer.Option(
        help="A Signal K access token, for a server with security on.")] = None,
    camera: Annotated[str | None, typer.Option(
        help="With live telemetry: a camera preset (dji-mavic3, dji-p4rtk, dji-m30-wide; "
        "follows the stream's size) or a calibration file of the stream's size.")] = None,
    water_level_m: Annotated[float | None, typer.Option(
        min=-1000.0, max=1000.0,
        help="With live telemetry: the water surface in the drone altitude's datum.")] = None,
    mount: Annotated[str, typer.Option(
        help="auto (the gimbal's attitude once it is heard, else stabilised), gimbal, "
        "stabilised or rigid, as in `telemetry video`.")] = "auto",
    camera_pitch_deg: Annotated[float, typer.Option(
        min=-90.0, max=0.0, help="Stabilised or rigid mount: the camera's pitch.")] = -90.0,
    camera_yaw_deg: Annotated[float | None, typer.Option(
        min=-360.0, max=360.0, help="A fixed camera yaw, for a feed without attitude.")] = None,
    video_delay_s: Annotated[float, typer.Option(
        min=0.0, max=10.0, help="How long frames take from the camera to here (encoder, link, "
        "decoder): a frame's time is its arrival less this.")] = 0.0,
    drone_offset_s: Annotated[float, typer.Option(
        min=-60.0, max=60.0, help="Added to the drone's sample times (its own delay).")] = 0.0,
    vessel_offset_s: Annotated[float, typer.Option(
        min=-60.0, max=60.0, help="Added to the vessel's fix times (its own delay).")] = 0.0,
    hold_s: Annotated[float, typer.Option(
        min=0.0, max=10.0, help="How long a feed's newest sample stands for a newer frame; "
        "later frames are not measured.")] = 1.0,
    http: Annotated[str | None, typer.Option(
        help="Serve the dashboard, GET /api/state and the /ws WebSocket here, e.g. "
        "127.0.0.1:8080 (port 0: a free one).")] = None,
    realtime: Annotated[bool, typer.Option(
        help="Play a file at its frame rate (frames the measurement cannot keep up with are "
        "dropped); --no-realtime reads as fast as frames decode.")] = True,
    model: Annotated[Path | None, typer.Option(
        help="ONNX segmentation model. Default: the packaged model.")] = None,
    vessel: Annotated[Path | None, typer.Option(
        help="Vessel spec (vessel.yaml). Default: each frame's vessel_spec key (needed with "
        "live telemetry).")] = None,
    caution_m: Annotated[float, typer.Option(min=0.01, max=1000.0,
                                             help="Caution at or below this distance.")] = 5.0,
    danger_m: Annotated[float, typer.Option(min=0.01, max=1000.0,
                                            help="Danger at or below this distance.")] = 2.0,
    ttc_s: Annotated[float, typer.Option(
        min=0.1, max=3600.0, help="Caution when the time to contact is this short; danger "
        "when also within --caution-m.")] = 30.0,
    record: Annotated[Path | None, typer.Option(
        help="Record the session in DIR as it goes: every published state (states.jsonl), "
        "every measured frame with its metadata (images/, frames/: a flight `harborsight run "
        "DIR` replays) and what `run` writes (reports/, sections.csv, annotated.mp4 in "
        "fragmented MP4, run.json, timeline.png at the end); each file whole as it is "
        "written, so a killed session leaves a readable record.")] = None,
    refine_pose: Annotated[bool, typer.Option(help=REFINE_POSE_HELP)] = True,
    own_motion: Annotated[bool, typer.Option(help=OWN_MOTION_HELP)] = True,
    sigma: Annotated[list[str] | None, typer.Option(metavar="NAME=VALUE", help=SIGMA_HELP)] = None,
    segment_gsd_m: Annotated[float, typer.Option(
        help=SEGMENT_GSD_HELP + " Live, each window is one more model call in the frame's "
        "latency: benchmarks/bench_live.py measures what a machine keeps up with.")] = 0.0,
) -> None:
    """Live clearances: the newest frame measured (older ones dropped, so the latency does
    not grow), per-section ok / caution / danger with hysteresis, closing speed and time to
    contact, stale-data alarms when the video is older than 1 s or the poses older than 2 s;
    the state as JSON (schema harborsight.live/1) at /api/state, pushed on /ws, the
    annotated frames as MJPEG at /video.mjpg, and a dashboard at /. The poses come from the
    file's metadata (--metadata), or live from the drone (--mavlink) and the vessel (--nmea),
    time-aligned to the frames. Ctrl-C stops it."""
    from harborsight.flight import VideoSource
    from harborsight.live.alarms import AlarmSettings
    from harborsight.live.engine import LiveEngine
    from harborsight.live.server import LiveServer
    from harborsight.live.session import file_reader, run_live
    from harborsight.live.signalk import SignalKPublisher, stream_url
    from harborsight.live.stream import VideoFrames
    from harborsight.live.video_in import RTSP_TRANSPORTS, is_stream, read_stream
    from harborsight.telemetry.ais import AIS_DEAD_RECKON_S

    server = None
    try:
        address = _host_port(http) if http else None
        if rtsp_transport not in RTSP_TRANSPORTS:
            raise InputError(None, "--rtsp-transport", f"{rtsp_transport!r}: expected tcp or udp")
        try:
            # AIS reports every 10 s and carries the vessel between them (its bars widened)
            alarms = AlarmSettings(caution_m=caution_m, danger_m=danger_m, ttc_s=ttc_s,
                                   vessel_stale_s=AIS_DEAD_RECKON_S if ais is not None else None)
        except ValueError as exc:
            raise InputError(None, "--danger-m", str(exc)) from None
        signalk_out_url = stream_url(signalk_out, "--signalk-out") if signalk_out else None
        live_telemetry = any(v is not None for v in (mavlink, nmea, signalk, ais))
        if live_telemetry and metadata is not None:
            raise InputError(None, "--metadata", "give the file's metadata or live telemetry "
                             "(--mavlink, --nmea), not both")
        if not live_telemetry and metadata is None:
            raise InputError(None, "--metadata", "give the video's metadata, or live telemetry "
                             "with --mavlink and --nmea")
        if live_telemetry:
            if sum(v is not None for v in (nmea, signalk, ais)) > 1:
                raise InputError(None, "--signalk" if signalk else "--ais", "the vessel comes "
                                 "from one of --nmea, --signalk and --ais")
            for option, value in (("--mavlink", mavlink), ("--nmea", nmea or signalk or ais),
                                  ("--camera", camera), ("--water-level-m", water_level_m),
                                  ("--vessel", vessel)):
                if value is None:
                    raise InputError(None, option, "needed with live telemetry (the vessel: "
                                     "--nmea, --signalk or --ais)" if option == "--nmea" else
                                     "needed with live telemetry")
        elif is_stream(video):
            raise InputError(None, "--metadata", "a stream's poses come live: give --mavlink "
                             "and --nmea instead")
        engine = LiveEngine(load_segmenter(model, segment_gsd_m=segment_gsd_m),
                            vessel_cache(vessel),
                            clearance_settings(Method.ground_plane, None, None, POSE_MARGIN_PX, OWN_RIM_PX,
                                               refine_pose, sigma, own_motion),
                            alarms)
        feeds, composer = [], None
        if live_telemetry:
            feeds, composer = _feeds_setup(
                engine, mavlink=mavlink, mavlink_altitude=mavlink_altitude, nmea=nmea,
                signalk=signalk, signalk_token=signalk_token, ais=ais, mmsi=mmsi,
                allow_cog_heading=allow_cog_heading,
                camera=camera, water_level_m=water_level_m, mount=mount,
                camera_pitch_deg=camera_pitch_deg, camera_yaw_deg=camera_yaw_deg,
                video_delay_s=video_delay_s, drone_offset_s=drone_offset_s,
                vessel_offset_s=vessel_offset_s, hold_s=hold_s)
        if is_stream(video):
            def frames(box, stop, on_arrival):
                read_stream(video, box, stop, on_arrival, lambda message: engine.warn("video", message),
                            rtsp_transport=rtsp_transport)
        elif metadata is not None:
            frames = file_reader(VideoSource(Path(video), metadata), realtime)
        else:
            frames = file_reader(VideoFrames(Path(video)), realtime)
        publishers = []
        if signalk_out_url is not None:
            signalk_publisher = SignalKPublisher(signalk_out_url, token=signalk_token,
                                                 warn=lambda message: engine.warn("signalk", message))
            publishers.append(signalk_publisher.publish)
            feeds = [*feeds, signalk_publisher.run]
        if address is not None:
            server = LiveServer(engine.state, *address, get_jpeg=engine.annotated_jpeg,
                                get_frame_index=lambda: engine.frame_index)
            try:
                server.start()
            except OSError as exc:
                raise InputError(None, "--http", str(exc)) from None
            console.print(f"dashboard: http://{server.host}:{server.port}/  state: "
                          f"http://{server.host}:{server.port}/api/state", highlight=False)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    _stop_on_sigterm()
    try:        # Ctrl-C (or SIGTERM) ends the loop; run_live still returns what it measured
        if server is not None:
            publishers.append(server.publish)

        def publish(state: dict) -> None:
            for send in publishers:
                send(state)
        summary = run_live(frames, engine, composer=composer, feeds=feeds,
                           publish=publish if publishers else None, record=record,
                           record_inputs={"video": video, "metadata": str(metadata) if metadata else None,
                                          "mavlink": mavlink, "nmea": nmea, "signalk": signalk,
                                          "ais": ais, "vessel": str(vessel) if vessel else None})
    finally:
        if server is not None:
            server.stop()
    p50, p95 = summary.latency_percentile_ms(50), summary.latency_percentile_ms(95)
    console.print(
        f"{summary.frames_measured} frame(s) measured of {summary.frames_received} received "
        f"({summary.frames_dropped} dropped to keep up, {summary.frames_skipped} not measurable) "
        f"in {summary.seconds:.1f} s"
        + ("" if p95 is None else f"; latency median {p50:.0f} ms, p95 {p95:.0f} ms"),
        highlight=False)


def _stop_on_sigterm() -> None:
    """SIGTERM (a service manager stopping the aid) ends it as Ctrl-C does: cleanly, with the
    record closed and the summary printed."""
    import signal
    import threading

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():     # not when called in a test's thread
        signal.signal(signal.SIGTERM, interrupt)


@app.command("live-feed")
def live_feed_command(
    video: Annotated[Path, typer.Argument(help="The flight's video.")],
    drone_log: Annotated[Path, typer.Option(
        help="The drone's log (DJI .srt, PX4 .ulg, ArduPilot .bin), sent as MAVLink.")],
    vessel_track: Annotated[Path, typer.Option(
        help="The vessel's NMEA 0183 log, sent line by line at its fixes' times; or its AIS "
        "log (receiver times in tag blocks or before each line; for `live --ais`), each report "
        "at its time, stamped with the second it goes out at.")],
    video_to: Annotated[str, typer.Option(
        help="Where the video goes: an MPEG-TS URL (udp://HOST:PORT), or an RTSP server to "
        "publish to (rtsp://HOST:PORT/PATH).")] = "udp://127.0.0.1:5600",
    rtsp_transport: Annotated[str, typer.Option(
        help="Publishing to rtsp://: RTP over tcp or udp.")] = "tcp",
    mavlink_to: Annotated[str, typer.Option(
        help="Where MAVLink goes (pymavlink address).")] = "udpout:127.0.0.1:14550",
    nmea_to: Annotated[str, typer.Option(
        help="Where NMEA goes: UDP HOST:PORT.")] = "127.0.0.1:10110",
    start_s: Annotated[float, typer.Option(min=0.0, help="Flight time to start at.")] = 0.0,
    duration_s: Annotated[float | None, typer.Option(
        min=0.1, help="How much of the flight to send (default: to the video's end).")] = None,
    video_start: Annotated[str | None, typer.Option(
        help="UTC time of the video's first frame, ISO 8601 (default: the SRT's date lines, "
        "else the vessel's first fix; for an AIS log, its first line with a receiver time, "
        "whichever vessel's: give this with a log of several vessels).")] = None,
    utc_offset_h: Annotated[float | None, typer.Option(
        min=-14.0, max=14.0, help="A DJI SRT's local date lines: hours ahead of UTC.")] = None,
) -> None:
    """Play a recorded flight as the live feeds a drone and a ship send, in real time: video
    as H.264 MPEG-TS over UDP (or published to an RTSP server), the drone's log as MAVLink,
    the vessel's NMEA (or AIS) over UDP. For
    rehearsing `harborsight live --video udp://... --mavlink ... --nmea ...` (or `--ais`)."""
    from harborsight.live.feed import FeedPlan, play_flight
    from harborsight.telemetry.metadata import parse_utc_time

    try:
        for path, option in ((video, "VIDEO"), (drone_log, "--drone-log"),
                             (vessel_track, "--vessel-track")):
            if not path.is_file():
                raise InputError(path, option, "file not found")
        host, _, port = nmea_to.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) <= 65535:
            raise InputError(None, "--nmea-to", f"expected HOST:PORT, got {nmea_to!r}")
        if not video_to.startswith(("udp://", "rtp://", "srt://", "tcp://", "rtsp://")):
            raise InputError(None, "--video-to", f"expected an MPEG-TS URL such as "
                             f"udp://127.0.0.1:5600 or an rtsp:// server, got {video_to!r}")
        if rtsp_transport not in ("tcp", "udp"):
            raise InputError(None, "--rtsp-transport", f"{rtsp_transport!r}: expected tcp or udp")
        plan = FeedPlan(video, drone_log, vessel_track, video_to, mavlink_to, nmea_to, start_s,
                        duration_s, parse_utc_time(video_start, "--video-start") if video_start else None,
                        utc_offset_h, rtsp_transport=rtsp_transport)
        console.print(f"sending {video.name} to {video_to}, {drone_log.name} as MAVLink to "
                      f"{mavlink_to}, {vessel_track.name} to udp {nmea_to}", highlight=False)
        summary = play_flight(plan)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    console.print(f"sent {summary.frames} frame(s), {summary.mavlink_messages} MAVLink "
                  f"message(s), {summary.nmea_lines} vessel line(s) (NMEA or AIS); 95 % went out within "
                  f"{summary.lateness_p95_ms():.0f} ms of their time", highlight=False)
