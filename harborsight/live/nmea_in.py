"""The vessel's live NMEA 0183 feed: ``--nmea udp:10110`` (listen on a port, as most
multiplexers and OpenCPN broadcast), ``udp:HOST:PORT`` (listen on one address),
``tcp:HOST:PORT`` (connect, and reconnect when dropped) or a serial device
``/dev/ttyUSB0[@BAUD]`` (4800 by default, NMEA 0183's rate; pyserial).

Sentences are decoded by :class:`harborsight.telemetry.nmea.NmeaDecoder`, the file reader's
decoder. Each new fix goes into the vessel's :class:`~harborsight.live.telemetry.LiveTrack`
at its UTC time mapped to the monotonic clock; its sigma from the GGA quality class (widened
by HDOP), as in files (a GST is not waited for live). Headings have no time of their own:
each takes its arrival time less the delay of the fix before it. Magnetic headings (HDM, HDG
without variation) are made true with the WMM declination at the last fix. Unreadable
sentences and skipped ones are counted, and warned about as they first occur.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

from harborsight.errors import InputError
from harborsight.live.telemetry import LiveTrack
from harborsight.telemetry.accuracy import GGA_QUALITY_CLASSES, per_axis_from_class_m
from harborsight.telemetry.nmea import Fix, Gst, Heading, NmeaDecoder, RateOfTurn
from harborsight.telemetry.track import POSITION_GAP_DEAD_RECKON_S

#: a heading sensor heard within this many seconds keeps a worse one's headings out
HEADING_SENSOR_HOLD_S = 2.0


@dataclass(frozen=True)
class NmeaAddress:
    kind: str            # udp, tcp, serial
    host: str            # udp: address to bind; tcp: server; serial: device
    port: int            # udp/tcp port; serial: baud rate

    def __str__(self) -> str:
        return f"{self.kind}:{self.host}:{self.port}"


def parse_nmea_address(text: str, option: str = "--nmea") -> NmeaAddress:
    """``udp:PORT``, ``udp:HOST:PORT``, ``tcp:HOST:PORT`` or ``DEVICE[@BAUD]`` (an error
    names ``option``)."""
    kind, _, rest = text.partition(":")
    try:
        if kind == "udp":
            host, _, port = rest.rpartition(":")
            address = NmeaAddress("udp", host or "0.0.0.0", int(port))
        elif kind == "tcp":
            host, _, port = rest.rpartition(":")
            if not host:
                raise ValueError
            address = NmeaAddress("tcp", host, int(port))
        elif text.startswith("/dev/") or text.upper().startswith("COM"):
            device, _, baud = text.partition("@")
            return NmeaAddress("serial", device, int(baud or 4800))
        else:
            raise ValueError
    except ValueError:
        raise InputError(None, option, f"expected udp:PORT, udp:HOST:PORT, tcp:HOST:PORT or a "
                         f"serial device such as /dev/ttyUSB0@4800, got {text!r}") from None
    if not 0 < address.port <= 65535:
        raise InputError(None, option, f"port {address.port} is not 1-65535")
    return address


class NmeaVessel:
    """Feeds lines into the vessel's live track (module docstring)."""

    def __init__(self, track: LiveTrack, *, on_fix: Callable[[float], None] | None = None) -> None:
        self.track, self.on_fix = track, on_fix
        # live: a GGA before any date sentence is dated by this machine's clock (a GNSS
        # compass may send GGA, HDT and VTG only)
        self.decoder = NmeaDecoder(now_utc=lambda: datetime.now(UTC))
        track.source_clock_is_utc()
        self._fix_delay_s = 0.0                   # mapped time − arrival of the last fix
        self._last_fix: Fix | None = None
        self._last_fix_t_s: float | None = None   # its mapped time
        # a receiver that loses its fix for a few seconds: the RMC's speed and course carry
        track.dead_reckon_s = POSITION_GAP_DEAD_RECKON_S
        self._declination: tuple[tuple[float, float], float] | None = None
        self._warned: set[str] = set()
        #: heading sensors heard (talker: best rank, last heard), and those said left out
        self._heading_sensors: dict[str, tuple[tuple[int, int], float]] = {}
        self._heading_sensors_said: set[str] = set()
        self.lines = 0

    def _warn_new_kinds(self) -> None:
        """Warn the first time each kind of skipped or unreadable sentence occurs."""
        for note in self.decoder.notes():
            kind = note.split(" ", 1)[1].split(";")[0]
            if kind not in self._warned:
                self._warned.add(kind)
                self.track.warn(f"NMEA: {note}")

    def feed(self, line: str, now_s: float) -> None:
        self.lines += 1
        bad_before = self.decoder.bad_count + sum(self.decoder.skipped.values())
        for event in self.decoder.feed(line, self.lines):
            if isinstance(event, Fix):
                if not event.new:            # the epoch's other sentence: its RMC's motion
                    if math.isfinite(event.sog_mps) and self._last_fix_t_s is not None:
                        self.track.add_motion(self._last_fix_t_s, event.sog_mps, event.cog_deg)
                    continue
                t_s = self.track.clock.observe(event.utc.timestamp(), now_s)
                self._last_fix_t_s = t_s
                self._fix_delay_s = t_s - now_s
                self._last_fix = event
                sigma = math.nan
                if event.quality is not None:
                    sigma = float(per_axis_from_class_m([event.quality], [event.hdop],
                                                        GGA_QUALITY_CLASSES)[0])
                jumps = self.track.clock.jumps
                self.track.add_position(t_s, event.lat_deg, event.lon_deg, sigma_m=sigma,
                                        sog_mps=event.sog_mps, cog_deg=event.cog_deg)
                if self.track.clock.jumps != jumps:
                    self.track.warn("the vessel's clock jumped: its time alignment starts again")
                if self.on_fix is not None:
                    self.on_fix(now_s)
            elif isinstance(event, Heading):
                if not self._heading_source_used(event, now_s):
                    continue
                degrees = event.deg if event.true else self._made_true(event.deg)
                if degrees is not None:
                    self.track.add_heading(now_s + self._fix_delay_s, degrees % 360.0)
            elif isinstance(event, RateOfTurn):
                if self._last_fix_t_s is not None:     # the newest fix's rate of turn
                    self.track.add_turn(self._last_fix_t_s, event.deg_s)
            elif isinstance(event, Gst):
                pass                      # live: the GGA's class stands (module docstring)
        if self.decoder.bad_count + sum(self.decoder.skipped.values()) != bad_before:
            self._warn_new_kinds()

    def _heading_source_used(self, heading: Heading, now_s: float) -> bool:
        """Whether this heading's sensor (its talker) is the one the track follows now: the
        best :func:`~harborsight.telemetry.nmea.heading_rank` (a true heading before a
        magnetic one) heard within :data:`HEADING_SENSOR_HOLD_S`, so a sensor that falls
        silent hands over to the next; each sensor left out is said once."""
        from harborsight.telemetry.nmea import heading_rank, heading_sensor

        sensor = heading_sensor(heading.source)
        rank = (0 if heading.true else 1, heading_rank(heading.source))
        self._heading_sensors[sensor] = (min(rank, self._heading_sensors.get(sensor, (rank, 0.0))[0]), now_s)
        better = [other for other, (other_rank, heard_s) in self._heading_sensors.items()
                  if other != sensor and other_rank < self._heading_sensors[sensor][0]
                  and now_s - heard_s <= HEADING_SENSOR_HOLD_S]
        if better:
            if sensor not in self._heading_sensors_said:
                self._heading_sensors_said.add(sensor)
                self.track.warn(f"NMEA: headings from {sensor or 'no talker'} left out while "
                                f"{better[0] or 'no talker'} speaks (a better heading sentence)")
            return False
        return True

    def _made_true(self, magnetic_deg: float) -> float | None:
        from harborsight.telemetry.declination import magnetic_declination_deg

        fix = self._last_fix
        if fix is None:
            return None
        key = (round(fix.lat_deg, 2), round(fix.lon_deg, 2))
        if self._declination is None or self._declination[0] != key:
            try:
                self._declination = (key, magnetic_declination_deg(fix.lat_deg, fix.lon_deg, fix.utc))
            except ValueError as exc:
                self.track.warn(f"NMEA: a magnetic heading cannot be made true: {exc}")
                return None
        return magnetic_deg + self._declination[1]


def run_nmea(address: NmeaAddress, vessel: NmeaVessel, stop: threading.Event,
             sock: socket.socket | None = None) -> None:
    """Read ``address`` until ``stop`` is set, reconnecting when a connection drops; a UDP
    address on ``sock`` where it was opened beforehand (:func:`open_udp`)."""
    if address.kind == "udp":
        _run_udp(address, vessel, stop, sock)
    elif address.kind == "tcp":
        _run_tcp(address, vessel, stop)
    else:
        _run_serial(address, vessel, stop)


def open_udp(address: NmeaAddress, option: str = "--nmea") -> socket.socket:
    """The bound UDP socket (:class:`InputError` naming ``--nmea`` if the port is taken)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((address.host, address.port))
    except OSError as exc:
        sock.close()
        raise InputError(None, option, f"cannot listen on {address}: {exc.strerror or exc}") from None
    sock.settimeout(0.2)
    return sock


def _lines(buffer: bytearray, data: bytes, vessel: NmeaVessel) -> None:
    buffer.extend(data)
    now = time.monotonic()
    *complete, rest = buffer.split(b"\n")
    for raw in complete:
        vessel.feed(raw.decode("ascii", errors="replace"), now)
    buffer[:] = rest[-4096:]               # a line never runs this long: garbage is dropped


def _run_udp(address: NmeaAddress, vessel: NmeaVessel, stop: threading.Event,
             sock: socket.socket | None = None) -> None:
    sock = sock or open_udp(address)
    with sock:
        while not stop.is_set():
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as exc:
                vessel.track.warn(f"NMEA UDP read failed: {exc}")
                stop.wait(0.5)
                continue
            buffer = bytearray()           # a datagram holds whole sentences
            _lines(buffer, data if data.endswith(b"\n") else data + b"\n", vessel)


def _run_tcp(address: NmeaAddress, vessel: NmeaVessel, stop: threading.Event) -> None:
    while not stop.is_set():
        try:
            sock = socket.create_connection((address.host, address.port), timeout=2.0)
        except OSError as exc:
            vessel.track.warn(f"NMEA: cannot connect to {address.host}:{address.port} "
                              f"({exc.strerror or exc}); retrying")
            stop.wait(1.0)
            continue
        sock.settimeout(0.2)
        buffer = bytearray()
        with sock:
            while not stop.is_set():
                try:
                    data = sock.recv(65536)
                except TimeoutError:
                    continue
                except OSError as exc:
                    vessel.track.warn(f"NMEA TCP connection lost: {exc}; reconnecting")
                    break
                if not data:
                    vessel.track.warn("NMEA TCP connection closed by the server; reconnecting")
                    break
                _lines(buffer, data, vessel)
        stop.wait(0.5)


def _run_serial(address: NmeaAddress, vessel: NmeaVessel, stop: threading.Event) -> None:
    import serial

    while not stop.is_set():
        try:
            port = serial.Serial(address.host, address.port, timeout=0.2)
        except (OSError, serial.SerialException) as exc:
            vessel.track.warn(f"NMEA: cannot open {address.host}: {exc}; retrying")
            stop.wait(1.0)
            continue
        buffer = bytearray()
        with port:
            while not stop.is_set():
                try:
                    data = port.read(4096)
                except (OSError, serial.SerialException) as exc:
                    vessel.track.warn(f"NMEA serial read failed: {exc}; reopening")
                    break
                if data:
                    _lines(buffer, data, vessel)
        stop.wait(0.5)
