"""``harborsight live``: the berthing aid while the ship berths (a thin shell over
:mod:`harborsight.live`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from harborsight.cli.app import (
    OWN_RIM_PX,
    POSE_MARGIN_PX,
    REFINE_POSE_HELP,
    SIGMA_HELP,
    Method,
    app,
    clearance_settings,
    console,
    err_console,
    load_segmenter,
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


@app.command("live")
def live_command(
    video: Annotated[Path, typer.Option(
        help="The drone's video: a file (with --realtime it plays at its own frame rate, as a "
        "stream would arrive).")],
    metadata: Annotated[Path, typer.Option(
        help="JSON lines, one harborsight.frame/1 object per video frame (drone and vessel "
        "poses), replayed on the video's clock.")],
    http: Annotated[str | None, typer.Option(
        help="Serve the dashboard, GET /api/state and the /ws WebSocket here, e.g. "
        "127.0.0.1:8080 (port 0: a free one).")] = None,
    realtime: Annotated[bool, typer.Option(
        help="Play a file at its frame rate (frames the measurement cannot keep up with are "
        "dropped); --no-realtime reads as fast as frames decode.")] = True,
    model: Annotated[Path | None, typer.Option(
        help="ONNX segmentation model. Default: the packaged model.")] = None,
    vessel: Annotated[Path | None, typer.Option(
        help="Vessel spec (vessel.yaml). Default: each frame's vessel_spec key.")] = None,
    caution_m: Annotated[float, typer.Option(min=0.01, max=1000.0,
                                             help="Caution at or below this distance.")] = 5.0,
    danger_m: Annotated[float, typer.Option(min=0.01, max=1000.0,
                                            help="Danger at or below this distance.")] = 2.0,
    ttc_s: Annotated[float, typer.Option(
        min=0.1, max=3600.0, help="Caution when the time to contact is this short; danger "
        "when also within --caution-m.")] = 30.0,
    record: Annotated[Path | None, typer.Option(
        help="Write every published state to DIR/states.jsonl and every measured frame with "
        "its metadata to DIR/images and DIR/frames (a flight `harborsight run DIR` replays), "
        "each file whole as it is written.")] = None,
    refine_pose: Annotated[bool, typer.Option(help=REFINE_POSE_HELP)] = True,
    sigma: Annotated[list[str] | None, typer.Option(metavar="NAME=VALUE", help=SIGMA_HELP)] = None,
) -> None:
    """Live clearances: the newest frame measured (older ones dropped, so the latency does
    not grow), per-section ok / caution / danger with hysteresis, closing speed and time to
    contact, stale-data alarms when the video is older than 1 s or the poses older than 2 s;
    the state as JSON (schema harborsight.live/1) at /api/state, pushed on /ws, the
    annotated frames as MJPEG at /video.mjpg, and a dashboard at /. Ctrl-C stops it."""
    from harborsight.flight import VideoSource
    from harborsight.live.alarms import AlarmSettings
    from harborsight.live.engine import LiveEngine
    from harborsight.live.server import LiveServer
    from harborsight.live.session import file_reader, run_live
    from harborsight.pipeline import VesselCache
    from harborsight.vessel.spec import load_vessel_spec

    server = None
    try:
        address = _host_port(http) if http else None
        try:
            alarms = AlarmSettings(caution_m=caution_m, danger_m=danger_m, ttc_s=ttc_s)
        except ValueError as exc:
            raise InputError(None, "--danger-m", str(exc)) from None
        source = VideoSource(video, metadata)
        engine = LiveEngine(load_segmenter(model),
                            VesselCache(load_vessel_spec(vessel) if vessel else None),
                            clearance_settings(Method.ground_plane, None, None, POSE_MARGIN_PX, OWN_RIM_PX,
                                               refine_pose, sigma),
                            alarms)
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
    try:        # Ctrl-C ends the loop; run_live still returns what it measured
        summary = run_live(file_reader(source, realtime), engine,
                           publish=server.publish if server else None, record=record)
    finally:
        if server is not None:
            server.stop()
    p50, p95 = summary.latency_percentile_ms(50), summary.latency_percentile_ms(95)
    console.print(
        f"{summary.frames_measured} frame(s) measured of {summary.frames_received} received "
        f"({summary.frames_dropped} dropped to keep up) in {summary.seconds:.1f} s"
        + ("" if p95 is None else f"; latency median {p50:.0f} ms, p95 {p95:.0f} ms"),
        highlight=False)
