"""Flights: the vessel of a harbour scene berthing toward its nearest obstacle over time.

A sequence frame at time ``t`` is its scene with the vessel moved by ``p(t) = u·s(t)`` in
the harbour, where ``u`` is the horizontal unit vector from the hull to its nearest obstacle
and ``s(t) = min(v·t, s_max)``: the vessel closes at ``v`` and stops when its clearance
reaches ``stop_gap_m`` (``s_max`` from a bisection on shapely distances). The world frame W
stays on the vessel's antenna, so the harbour (and the water) move by ``-p(t)`` and the
vessel's geodetic position moves by ``+p(t)``. The companion drone follows the vessel with
a small hover wander. The true closing speed of a section is ``v`` times the cosine between
``u`` and the section's outward direction to its obstacle, while the vessel moves.
"""

from __future__ import annotations

import dataclasses
import math
from datetime import UTC, datetime, timedelta

import numpy as np
from shapely import affinity
from shapely.ops import nearest_points

from harborsight.geometry.geodesy import GeoOrigin, enu_to_geodetic
from harborsight.sim.ground_truth import footprint_union
from harborsight.sim.scene import VESSEL_INSTANCE, HarbourScene, Part, SceneObject

#: the first frame of sequence scene i is this time plus i scene slots (:func:`scene_slot_s`)
SEQUENCE_EPOCH = datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC)


def _translated(obj: SceneObject, shift_enu: np.ndarray) -> SceneObject:
    parts = []
    for part in obj.parts:
        mesh = part.mesh.copy()
        mesh.apply_translation((shift_enu[0], shift_enu[1], 0.0))
        parts.append(Part(mesh, part.material))
    # its course kept: a boat under way has its wake in a flight too (it was dropped)
    return SceneObject(obj.name, obj.kind, obj.class_id, obj.instance_id, parts, obj.course_deg)


def approach_plan(scene: HarbourScene, stop_gap_m: float) -> tuple[np.ndarray, float, float]:
    """``(u, s_max, initial clearance)``: the unit direction from the hull to its nearest
    obstacle (the bow direction in open water) and how far the vessel can go along it
    before its clearance to any obstacle is ``stop_gap_m``."""
    hull = scene.objects[0].footprint()
    obstacles = footprint_union(scene.obstacle_footprints())
    heading = np.radians(scene.vessel_heading_deg)
    bow = np.array([np.sin(heading), np.cos(heading)])
    if obstacles.is_empty:
        return bow, 0.0, float("inf")
    clearance = float(hull.distance(obstacles))
    a, b = nearest_points(hull, obstacles)
    direction = np.array([b.x - a.x, b.y - a.y])
    norm = float(np.linalg.norm(direction))
    if norm < 1e-6:                  # touching already: it stays put
        return bow, 0.0, clearance
    u = direction / norm

    def gap_after(s: float) -> float:
        return float(affinity.translate(hull, u[0] * s, u[1] * s).distance(obstacles))

    lo, hi = 0.0, max(clearance - stop_gap_m, 0.0)
    if gap_after(hi) >= stop_gap_m - 1e-6:
        return u, hi, clearance
    for _ in range(30):              # another obstacle is nearer along u: bisect
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap_after(mid) >= stop_gap_m else (lo, mid)
    return u, lo, clearance


def scene_slot_s(n_frames: int, interval_s: float) -> float:
    """Seconds between the first frames of consecutive scenes: whole minutes, one for a
    flight shorter than a minute, more for longer ones, so that a dataset's timestamps
    never run backwards from one scene to the next."""
    return 60.0 * max(1, math.floor((n_frames - 1) * interval_s / 60.0) + 1)


def sequence_frame(scene: HarbourScene, scene_index: int, frame: int, interval_s: float,
                   speed_mps: float, rng: np.random.Generator, stop_gap_m: float = 0.5,
                   hover_sigma_m: float = 0.3, n_frames: int = 0) -> HarbourScene:
    """Frame ``frame`` of the berthing sequence of ``scene`` (module docstring); the flight
    has ``n_frames`` frames (spaces the scenes' clocks)."""
    time_s = frame * interval_s
    u, s_max, clearance = approach_plan(scene, stop_gap_m)
    travel_m = min(speed_mps * time_s, s_max)
    moving = speed_mps * time_s < s_max
    shift = -u * travel_m            # the harbour moves by -p(t) in W
    objects = [obj if obj.instance_id == VESSEL_INSTANCE else _translated(obj, shift)
               for obj in scene.objects]
    lat, lon, _ = enu_to_geodetic(np.array([u[0] * travel_m, u[1] * travel_m, 0.0]),
                                  scene.origin)
    wander = rng.normal(0.0, hover_sigma_m, 3) * np.array([1.0, 1.0, 0.5])
    slot_s = scene_slot_s(max(n_frames, frame + 1), interval_s)
    stamp = SEQUENCE_EPOCH + timedelta(seconds=scene_index * slot_s + time_s)
    return dataclasses.replace(
        scene, objects=objects, uav_enu=np.asarray(scene.uav_enu, float) + wander,
        yaw_deg=(scene.yaw_deg + float(rng.normal(0.0, 0.3))) % 360.0,   # frame.py: [-360, 360]
        origin=GeoOrigin(float(lat), float(lon), scene.origin.alt_m),
        timestamp=stamp.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
        water_anchor_xy=(float(shift[0]), float(shift[1])), water_time_s=time_s,
        sequence={"scene": scene_index, "frame": frame, "time_s": round(time_s, 6),
                  "direction_enu": [round(float(c), 6) for c in u],
                  "speed_mps": speed_mps if moving else 0.0,
                  "travel_m": round(travel_m, 6), "initial_clearance_m": round(clearance, 6),
                  "stop_gap_m": stop_gap_m},
    )

