"""Signal K, the boat's data bus (a ``signalk-server``; chart plotters and MFDs read it):
the vessel's pose in (``--signalk ws://HOST:3000``), the clearances and alarms out
(``--signalk-out ws://HOST:3000``), over the server's WebSocket stream
(``/signalk/v1/stream``, the ``websockets`` client; ``--signalk-token`` for a server with
security on). Both reconnect when the server goes away and warn about it.

In: the self vessel's ``navigation.position`` (``latitude``, ``longitude`` in degrees) and
``navigation.headingTrue`` (radians), and ``navigation.speedOverGround`` (m/s) and
``navigation.courseOverGroundTrue`` (radians), which carry the vessel for up to 5 s when the
position stops (:mod:`harborsight.telemetry.track`, "Dead reckoning"), each at its update's
``timestamp`` (UTC, mapped to the
monotonic clock as NMEA fixes are: :class:`~harborsight.live.telemetry.ClockMap`), one map per
source: a server stamps an NMEA 0183 position with its RMC's time and an NMEA 2000 heading
with its own clock, and one map shared by both read the heading as old as the clocks are apart
(1.5 s, at 3 degrees a second of turn, is 4.5 degrees). Only the
self vessel's deltas count (the server's hello names it), and each path keeps the first source
it is heard from (``$source``, else ``source.label``): a chart plotter's GPS and the AIS
transponder's 12 m apart, mixed, made the vessel jump between them. Other vessels' deltas
and other sources' values are counted, with a warning, and left out. What the server sends
within :data:`REPLAY_WINDOW_S` of a (re)subscription is its cache of the paths' last values,
stamped when they were last updated, which may be long ago (a GPS that stopped): it is left
out, so that only live updates make the vessel current.

Out, as deltas from source ``harborsight`` to the self vessel:

* ``notifications.harborsight.section<k>``: ``state`` ``normal`` (ok), ``warn`` (caution),
  ``alarm`` (danger), with ``method`` (visual; sound too for an alarm) and ``message``; sent
  when a section's state changes;
* ``notifications.harborsight.stale``: ``alert`` while a source is stale (the distances are
  not current), ``normal`` when none is;
* ``harborsight.clearance.minimum`` and ``harborsight.clearance.section<k>.distance`` (m),
  ``.closingSpeed`` (m/s), ``.timeToContact`` (s), at most every ``interval_s`` (0.5 s); a
  value not known now is sent as null.
"""

from __future__ import annotations

import json
import math
import threading
import time
from datetime import datetime
from urllib.parse import urlsplit, urlunsplit

from harborsight.errors import InputError
from harborsight.live.telemetry import LiveTrack, SenderClocks, worth_saying
from harborsight.telemetry.track import POSITION_GAP_DEAD_RECKON_S

STREAM_PATH = "/signalk/v1/stream"
#: updates that arrive this soon after subscribing are the server's cached values (s)
REPLAY_WINDOW_S = 0.5
#: the Signal K paths of the vessel's motion over ground, and what each sets
MOTION_PATHS = {"navigation.speedOverGround": "sog_mps",
                "navigation.courseOverGroundTrue": "cog_deg"}
#: a section's status as a Signal K notification state
NOTIFICATION_STATES = {"ok": "normal", "caution": "warn", "danger": "alarm",
                       "pose_contradicted": "alert"}
#: Signal K's notification states, least grave first
SEVERITY = ("normal", "alert", "warn", "alarm")


def stream_url(text: str, option: str) -> str:
    """The server's stream URL from ``ws://HOST:PORT`` (or ``wss://``, or a full stream
    URL); :class:`InputError` naming ``option`` otherwise."""
    parts = urlsplit(text)
    if parts.scheme not in ("ws", "wss") or not parts.hostname:
        raise InputError(None, option, f"expected ws://HOST:PORT of a Signal K server, got {text!r}")
    try:
        _ = parts.port
    except ValueError:
        raise InputError(None, option, f"bad port in {text!r}") from None
    path = parts.path.rstrip("/")
    if not path.endswith(STREAM_PATH):
        path = path + STREAM_PATH
    return urlunsplit((parts.scheme, parts.netloc, path, "subscribe=none", ""))


def _connect(url: str, token: str | None):
    from websockets.sync.client import connect

    headers = {"Authorization": f"Bearer {token}"} if token else None
    return connect(url, open_timeout=5, additional_headers=headers)


class SignalKVessel:
    """The self vessel's position and heading from a Signal K server into a live track."""

    def __init__(self, url: str, track: LiveTrack, *, token: str | None = None,
                 on_fix=None) -> None:
        self.url, self.track, self.token, self.on_fix = url, track, token, on_fix
        track.source_clock_is_utc()
        # a position source that stops for a few seconds: its speed and course carry the vessel
        track.dead_reckon_s = POSITION_GAP_DEAD_RECKON_S
        #: the newest speed (m/s) and course (deg) over ground and their time (an update's
        #: values share it): they go with the position of that time, whichever comes first
        self._motion: dict[str, float] = {}
        self.updates = 0
        self.unreadable = 0
        #: the self vessel's context, from the server's hello
        self.self_context: str | None = None
        #: the source each path is read from: the first heard
        self.sources: dict[str, str] = {}
        #: each source's clock map; the position's source maps with the track's own (the
        #: frames' UTC times are read through it)
        self.clocks = SenderClocks(track)
        self.other_vessels = 0
        self.other_sources = 0
        #: when the last subscription was sent (monotonic), and the cached values left out
        self.subscribed_s = -math.inf
        self.replayed = 0

    def handle(self, message: str, now_s: float) -> None:
        try:
            delta = json.loads(message)
        except ValueError:
            self.unreadable += 1
            return
        if (now_s - self.subscribed_s <= REPLAY_WINDOW_S and isinstance(delta, dict)
                and isinstance(delta.get("updates"), list)):
            self.replayed += 1
            if worth_saying(self.replayed, every=None):
                self.track.warn(f"Signal K: {self.replayed} message(s) of cached values the server "
                                "sent on subscribing left out (stamped when last updated, not now)")
            return
        if isinstance(delta, dict) and isinstance(delta.get("self"), str):
            self.self_context = delta["self"]       # the hello
        if not isinstance(delta, dict) or not isinstance(delta.get("updates"), list):
            return                                  # the hello, or not a delta
        context = delta.get("context")
        if context not in (None, "vessels.self") and self.self_context is not None \
                and context != self.self_context:
            self.other_vessels += 1
            if worth_saying(self.other_vessels, every=None):
                self.track.warn(f"Signal K: {self.other_vessels} delta(s) of other vessels "
                                f"({str(context)[:60]}) left out")
            return
        for update in delta["updates"]:
            try:
                stamp = datetime.fromisoformat(str(update["timestamp"]).replace("Z", "+00:00"))
                source = update.get("$source") or (update.get("source") or {}).get("label") or ""
                clock = self.clocks.of(source, primary=any(
                    isinstance(item, dict) and item.get("path") == "navigation.position"
                    for item in update.get("values", [])))
                jumps = clock.jumps
                t_s = clock.observe(stamp.timestamp(), now_s)
                if clock.jumps != jumps and worth_saying(clock.jumps, every=None):
                    self.track.warn(f"Signal K: the clock of source {source!r} jumped ({clock.jumps} "
                                    "time(s)): its time alignment starts again (a source that "
                                    "stamps with two clocks, or a server without time sync?)")
                for item in update.get("values", []):
                    path = item.get("path")
                    if self.sources.setdefault(path, source) != source:
                        self.other_sources += 1
                        if worth_saying(self.other_sources, every=None):
                            self.track.warn(f"Signal K: {path} also comes from {source!r}; "
                                            f"{self.sources[path]!r}, heard first, is kept "
                                            f"({self.other_sources} value(s) left out)")
                        continue
                    self._value(path, item.get("value"), t_s, now_s)
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                self.unreadable += 1
                if worth_saying(self.unreadable, every=None):
                    self.track.warn(f"Signal K: {self.unreadable} unreadable update(s) skipped ({exc})")

    def _value(self, path, value, t_s: float, now_s: float) -> None:
        if path == "navigation.position":
            lat, lon = float(value["latitude"]), float(value["longitude"])
            if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
                raise ValueError(f"position {lat}, {lon} is off the globe")
            self.track.add_position(t_s, lat, lon)
            self._motion_to_position(t_s)
            self.updates += 1
            if self.on_fix is not None:
                self.on_fix(now_s)
        elif path == "navigation.headingTrue" and value is not None:
            heading = math.degrees(float(value))
            if not math.isfinite(heading):
                raise ValueError(f"heading {value!r}")
            self.track.add_heading(t_s, heading % 360.0)
        elif path in MOTION_PATHS and value is not None:
            number = float(value)
            if not math.isfinite(number):
                raise ValueError(f"{path} {value!r}")
            if self._motion.get("t_s") != t_s:
                self._motion = {"t_s": t_s}
            self._motion[MOTION_PATHS[path]] = (number if path.endswith("speedOverGround")
                                                else math.degrees(number) % 360.0)
            self._motion_to_position(t_s)

    def _motion_to_position(self, t_s: float) -> None:
        """The speed and course of ``t_s`` to the position of ``t_s`` (whether they can carry
        it is the track's to say: :func:`~harborsight.telemetry.track.carried_by_motion`)."""
        motion = self._motion
        if motion.get("t_s") == t_s and "sog_mps" in motion:
            self.track.add_motion(t_s, motion["sog_mps"], motion.get("cog_deg", math.nan))

    def run(self, stop: threading.Event) -> None:
        subscribe = json.dumps({"context": "vessels.self", "subscribe": [
            {"path": "navigation.position", "policy": "instant"},
            {"path": "navigation.headingTrue", "policy": "instant"},
            *({"path": path, "policy": "instant"} for path in MOTION_PATHS)]})
        while not stop.is_set():
            try:
                with _connect(self.url, self.token) as socket:
                    socket.send(subscribe)
                    self.subscribed_s = time.monotonic()
                    while not stop.is_set():
                        try:
                            message = socket.recv(timeout=0.2)
                        except TimeoutError:
                            continue
                        self.handle(message, time.monotonic())
            except Exception as exc:      # refused, dropped, closed by the server
                if stop.is_set():
                    break
                self.track.warn(f"Signal K {self.url}: {exc}; reconnecting")
                stop.wait(1.0)


def _number(value, digits: int):
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


class SignalKPublisher:
    """Publishes the live state to a Signal K server (module docstring). :meth:`publish`
    only keeps the newest state; a thread of its own sends, so a slow or absent server never
    delays the measuring loop."""

    def __init__(self, url: str, *, token: str | None = None, interval_s: float = 0.5,
                 warn=None) -> None:
        self.url, self.token, self.interval_s = url, token, interval_s
        self.warn = warn or (lambda message: None)
        self._state: dict | None = None
        self._changed = threading.Event()
        self._sent_states: dict[str, str] = {}
        self._last_values_s = -math.inf
        self.deltas_sent = 0

    def publish(self, state: dict) -> None:
        self._state = state
        self._changed.set()

    def deltas(self, state: dict, now_s: float) -> list[dict]:
        """The deltas for ``state``: changed notifications, and the values when due."""
        values = []
        for section in state["sections"]:
            held = section.get("level", "ok")
            # the graver of the level the section holds and its status: a section in danger
            # that goes out of view keeps its alarm on the chart plotter too
            level = max(NOTIFICATION_STATES[held], NOTIFICATION_STATES.get(section["status"], "normal"),
                        key=SEVERITY.index)
            path = f"notifications.harborsight.section{section['index']}"
            if self._sent_states.get(path) != level:
                distance = section.get("distance_m")
                status = section["status"]
                said = status if held in (status, "ok") else f"{held} held ({status})"
                message = (f"harborsight section {section['index']}: {said}"
                           + ("" if distance is None else f", {distance:.1f} m"))
                values.append({"path": path, "value": {
                    "state": level, "message": message,
                    "method": ["visual", "sound"] if level == "alarm" else ["visual"]}})
                self._sent_states[path] = level
        stale = [a["message"] for a in state["alarms"] if a["kind"].startswith("stale_")]
        level = "alert" if stale else "normal"
        if self._sent_states.get("notifications.harborsight.stale") != level:
            values.append({"path": "notifications.harborsight.stale", "value": {
                "state": level, "method": ["visual"] if stale else [],
                "message": "; ".join(stale) if stale else "harborsight: all sources current"}})
            self._sent_states["notifications.harborsight.stale"] = level
        if now_s - self._last_values_s >= self.interval_s:
            self._last_values_s = now_s
            current = not state.get("stale")
            values.append({"path": "harborsight.clearance.minimum",
                           "value": _number(state.get("min_distance_m"), 3) if current else None})
            for section in state["sections"]:
                base = f"harborsight.clearance.section{section['index']}"
                for key, name, digits in (("distance_m", "distance", 3),
                                          ("closing_speed_mps", "closingSpeed", 3),
                                          ("time_to_contact_s", "timeToContact", 1)):
                    values.append({"path": f"{base}.{name}",
                                   "value": _number(section.get(key), digits) if current else None})
        if not values:
            return []
        return [{"context": "vessels.self",
                 "updates": [{"source": {"label": "harborsight"}, "values": values}]}]

    def run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                with _connect(self.url, self.token) as socket:
                    self._sent_states.clear()        # a new connection: say everything again
                    while not stop.is_set():
                        if not self._changed.wait(0.2):
                            continue
                        self._changed.clear()
                        state = self._state
                        for delta in self.deltas(state, time.monotonic()):
                            socket.send(json.dumps(delta))
                            self.deltas_sent += 1
                    self._flush(socket)
            except Exception as exc:      # refused, dropped, closed by the server
                if stop.is_set():
                    break
                self.warn(f"Signal K out {self.url}: {exc}; reconnecting")
                stop.wait(1.0)

    def _flush(self, socket) -> None:
        """On stopping: the last state's changes go out before the connection closes."""
        if self._state is not None:
            for delta in self.deltas(self._state, math.inf):
                socket.send(json.dumps(delta))
                self.deltas_sent += 1
