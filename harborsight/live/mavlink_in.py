"""The drone's live telemetry over MAVLink (pymavlink; ``--mavlink udpin:0.0.0.0:14550``,
``tcp:HOST:PORT``, a serial device, anything ``mavutil.mavlink_connection`` opens).

Messages read (MAVLink common and ArduPilot dialects, v1 and v2 frames):

* ``GLOBAL_POSITION_INT``: position (degE7) and altitude, on the autopilot's boot clock
  (``time_boot_ms``). Altitude ``relative`` (default): ``relative_alt``, height above the home
  point, barometer-fused and so steadier than GNSS altitude (give the water level in that
  datum: e.g. −2.5 for a take-off from a deck 2.5 m above the water); ``amsl``: ``alt``.
* ``GPS_RAW_INT``: ``h_acc`` (mm), the receiver's horizontal accuracy, as the position's sigma
  (radial, divided by √2 per axis).
* ``ATTITUDE``: the airframe's roll, pitch and yaw (radians), used where no gimbal attitude
  comes (a stabilised or rigid camera mount).
* ``GIMBAL_DEVICE_ATTITUDE_STATUS``: the gimbal's quaternion (w, x, y, z; FRD to NED). Its yaw
  is in the vehicle frame when the flags say ``YAW_IN_VEHICLE_FRAME`` (or neither frame flag and
  no ``YAW_LOCK``): the camera's rotation is then ``Rz(vehicle yaw) · R(q)``. ``MOUNT_STATUS``
  (ArduPilot's older message: pitch, roll, yaw in centidegrees, yaw relative to the vehicle)
  likewise. The vehicle's yaw is the newest ``ATTITUDE``'s only while it arrived within
  :data:`VEHICLE_YAW_MAX_AGE_S`: a vehicle-frame gimbal attitude is left out (counted and
  said) when ATTITUDE has stopped, rather than turned by a yaw of any age. A quaternion whose
  norm is not 1 (all zeros, as some gimbals send before they are ready) is left out too.
* ``SYSTEM_TIME``: UTC of the boot clock (the frames' timestamps).

Every message's boot time goes through :class:`harborsight.live.telemetry.ClockMap`, one
map per component: a gimbal that speaks MAVLink itself (its own component id) stamps
``GIMBAL_DEVICE_ATTITUDE_STATUS`` with its own boot time, and one map shared with the
autopilot's restarted at every message (clocks booted seconds apart) or, under 2 s apart,
put the camera's attitude that much off its position. A message without a boot time
(``MOUNT_STATUS``) takes its arrival time. Frames that fail their CRC are
counted and warned about, never read, and a position outside ±90° / ±180° is left out. The
drone is the first system (MAVLink system id) that
sends its position; these messages from any other system (a second vehicle on the link) are
counted, said and left out: mixed in, its position would be the drone's. A message that
cannot be read for any other reason is counted and said; the reader goes on.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
import time
from collections.abc import Callable

from harborsight.errors import InputError
from harborsight.live.telemetry import ClockMap, LiveTrack, SenderClocks, worth_saying
from harborsight.telemetry.accuracy import per_axis_from_radial_m

ALTITUDES = ("relative", "amsl")
#: the messages read at their sender's boot time (``time_boot_ms``)
_BOOT_STAMPED = frozenset({"GLOBAL_POSITION_INT", "ATTITUDE", "GIMBAL_DEVICE_ATTITUDE_STATUS"})
#: GIMBAL_DEVICE_FLAGS bits
_YAW_LOCK, _YAW_IN_VEHICLE_FRAME, _YAW_IN_EARTH_FRAME = 16, 32, 64
#: a gimbal's yaw relative to the airframe is turned by the vehicle's yaw only while the
#: newest ATTITUDE arrived at most this long before it (seconds)
VEHICLE_YAW_MAX_AGE_S = 1.0
#: a gimbal quaternion whose norm is further than this from 1 is not an attitude
QUATERNION_NORM_TOLERANCE = 0.1


def mavlink2():
    """pymavlink's ``mavutil`` with the MAVLink 2 ArduPilot dialect (a superset of common,
    parsing v1 frames too). mavutil picks v1 or v2 from ``MAVLINK20`` when a dialect is set,
    so it is set here whatever imported pymavlink first (v1 has no message above id 255, such
    as GIMBAL_DEVICE_ATTITUDE_STATUS)."""
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil

    return mavutil


def open_mavlink(address: str):
    """A pymavlink connection; :class:`InputError` naming ``--mavlink`` if it cannot open."""
    mavutil = mavlink2()
    try:
        return mavutil.mavlink_connection(address, source_system=254, autoreconnect=True,
                                          dialect="ardupilotmega")
    except Exception as exc:                     # pymavlink raises what its transport raises
        raise InputError(None, "--mavlink", f"cannot open {address!r}: {exc}") from None


def _euler_deg(q_wxyz, vehicle_yaw_deg: float | None) -> tuple[float, float, float]:
    from scipy.spatial.transform import Rotation

    w, x, y, z = (float(v) for v in q_wxyz)
    rotation = Rotation.from_quat([x, y, z, w])
    if vehicle_yaw_deg is not None:
        rotation = Rotation.from_euler("Z", vehicle_yaw_deg, degrees=True) * rotation
    yaw, pitch, roll = rotation.as_euler("ZYX", degrees=True)
    return float(yaw) % 360.0, float(pitch), float(roll)


#: the messages of the drone's own state: read from the drone's system id only
_DRONE_STATE = frozenset({"GLOBAL_POSITION_INT", "GPS_RAW_INT", "ATTITUDE",
                          "GIMBAL_DEVICE_ATTITUDE_STATUS", "MOUNT_STATUS", "SYSTEM_TIME"})


class MavlinkDrone:
    """Reads a MAVLink connection into a :class:`LiveTrack` (module docstring)."""

    def __init__(self, connection, track: LiveTrack, *, altitude: str = "relative",
                 on_position: Callable[[float], None] | None = None) -> None:
        if altitude not in ALTITUDES:
            raise InputError(None, "--mavlink-altitude", f"{altitude!r}: expected one of "
                             + ", ".join(ALTITUDES))
        self.connection, self.track, self.altitude = connection, track, altitude
        self.on_position = on_position
        self.track.utc_clock = None
        self._vehicle_yaw_deg: float | None = None
        self._vehicle_yaw_arrived_s = -math.inf
        self._sigma_m = math.nan
        self.bad_frames = 0
        #: messages left out: unreadable values (a zero quaternion, a position out of range),
        #: vehicle-frame gimbal attitudes with no recent ATTITUDE, and ones that raised
        self.bad_values = 0
        self.gimbal_without_vehicle_yaw = 0
        self.failed = 0
        self.messages = 0
        #: the drone's MAVLink system id: the first to send its position
        self.system_id: int | None = None
        #: each (system, component)'s boot clock; the autopilot's (the sender of the drone's
        #: first position) maps with the track's own, which its SYSTEM_TIME ties to UTC
        self.clocks = SenderClocks(track)
        self.other_systems = 0

    def _warn(self, message: str) -> None:
        self.track.warn(message)

    def _bad_value(self, what: str) -> None:
        self.bad_values += 1
        if worth_saying(self.bad_values):
            self._warn(f"{self.bad_values} MAVLink message(s) with unusable values left out "
                       f"(the latest: {what})")

    def _vehicle_yaw_at(self, now_s: float) -> float | None:
        """The vehicle's yaw for a gimbal attitude arriving at ``now_s``: the newest
        ATTITUDE's if it arrived within :data:`VEHICLE_YAW_MAX_AGE_S`, else None (said)."""
        if now_s - self._vehicle_yaw_arrived_s <= VEHICLE_YAW_MAX_AGE_S:
            return self._vehicle_yaw_deg
        if self._vehicle_yaw_deg is not None:
            self.gimbal_without_vehicle_yaw += 1
            if worth_saying(self.gimbal_without_vehicle_yaw):
                self._warn(f"{self.gimbal_without_vehicle_yaw} gimbal attitude(s) relative to the "
                           f"airframe left out: no ATTITUDE for {now_s - self._vehicle_yaw_arrived_s:.1f} s "
                           "to turn them by")
        return None

    def handle(self, message, now_s: float) -> None:
        kind = message.get_type()
        if kind == "BAD_DATA":
            self.bad_frames += 1
            if worth_saying(self.bad_frames):
                self._warn(f"{self.bad_frames} unreadable MAVLink frame(s) skipped (bad CRC or "
                           "garbage)")
            return
        self.messages += 1
        if kind in _DRONE_STATE:
            system = message.get_srcSystem()
            if self.system_id is None and kind == "GLOBAL_POSITION_INT":
                self.system_id = system
            if self.system_id is not None and system != self.system_id:
                self.other_systems += 1
                if worth_saying(self.other_systems):
                    self._warn(f"{self.other_systems} MAVLink message(s) of system {system} left "
                               f"out (the drone is system {self.system_id})")
                return
        track = self.track
        sender = (message.get_srcSystem(), message.get_srcComponent())
        if kind in _BOOT_STAMPED:
            clock = self.clocks.of(sender, primary=kind == "GLOBAL_POSITION_INT")
            jumps = clock.jumps
        if kind == "GLOBAL_POSITION_INT":
            if message.lat == 0 and message.lon == 0:
                return                                   # no position yet
            if abs(message.lat) > 90e7 or abs(message.lon) > 180e7:
                self._bad_value(f"GLOBAL_POSITION_INT lat {message.lat / 1e7:g}, lon {message.lon / 1e7:g}")
                return
            t_s = clock.observe(message.time_boot_ms / 1000.0, now_s)
            alt_m = (message.relative_alt if self.altitude == "relative" else message.alt) / 1000.0
            track.add_position(t_s, message.lat / 1e7, message.lon / 1e7, alt_m, self._sigma_m)
            if self.on_position is not None:
                self.on_position(now_s)
        elif kind == "GPS_RAW_INT":
            h_acc = getattr(message, "h_acc", 0) or 0
            self._sigma_m = float(per_axis_from_radial_m([h_acc / 1000.0])[0]) if h_acc > 0 else math.nan
        elif kind == "ATTITUDE":
            t_s = clock.observe(message.time_boot_ms / 1000.0, now_s)
            self._vehicle_yaw_deg = math.degrees(message.yaw) % 360.0
            self._vehicle_yaw_arrived_s = now_s
            track.add_attitude(t_s, self._vehicle_yaw_deg, math.degrees(message.pitch),
                               math.degrees(message.roll), "vehicle")
        elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            flags = int(message.flags)
            in_vehicle = bool(flags & _YAW_IN_VEHICLE_FRAME) or (
                not flags & (_YAW_IN_VEHICLE_FRAME | _YAW_IN_EARTH_FRAME) and not flags & _YAW_LOCK)
            vehicle_yaw = self._vehicle_yaw_at(now_s) if in_vehicle else None
            if in_vehicle and vehicle_yaw is None:
                return                   # its yaw is relative to the airframe's: wait for ATTITUDE
            if any(not math.isfinite(v) for v in message.q):
                return
            if abs(math.sqrt(sum(float(v) ** 2 for v in message.q)) - 1.0) > QUATERNION_NORM_TOLERANCE:
                self._bad_value(f"GIMBAL_DEVICE_ATTITUDE_STATUS q {list(message.q)}")
                return
            t_s = clock.observe(message.time_boot_ms / 1000.0, now_s)
            track.add_attitude(t_s, *_euler_deg(message.q, vehicle_yaw), "gimbal")
        elif kind == "MOUNT_STATUS":
            vehicle_yaw = self._vehicle_yaw_at(now_s)
            if vehicle_yaw is None:
                return
            track.add_attitude(now_s, (vehicle_yaw + message.pointing_c / 100.0) % 360.0,
                               message.pointing_a / 100.0, message.pointing_b / 100.0, "gimbal")
        elif kind == "SYSTEM_TIME" and message.time_unix_usec > 0 and self.clocks.primary_or_unknown(sender):
            if track.utc_clock is None:
                track.utc_clock = ClockMap(jump_s=1.0)
            track.utc_clock.observe(message.time_boot_ms / 1000.0, message.time_unix_usec / 1e6)
        if kind in _BOOT_STAMPED and clock.jumps != jumps:
            what = "the drone's clock" if clock is track.clock else "a gimbal's clock"
            self._warn(f"{what} jumped (a reboot or a time reset): its time alignment starts again")

    def run(self, stop: threading.Event) -> None:
        """Read until ``stop`` is set (the reader thread's body)."""
        while not stop.is_set():
            try:
                message = self.connection.recv_match(blocking=True, timeout=0.2)
            except Exception as exc:     # a transport error: say so and keep listening
                self._warn(f"MAVLink read failed: {exc}")
                stop.wait(0.5)
                continue
            if message is None:
                continue
            try:
                self.handle(message, time.monotonic())
            except Exception as exc:     # one message must not end the drone's telemetry
                self.failed += 1
                if worth_saying(self.failed):
                    self._warn(f"{self.failed} MAVLink message(s) could not be read (the latest, "
                               f"{message.get_type()}: {type(exc).__name__}: {exc})")
        with contextlib.suppress(Exception):     # closing a dead transport may raise anything
            self.connection.close()
