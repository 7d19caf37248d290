"""Working harbours: a commercial quay with ships ahead and astern, its vehicles and people
(:func:`build_commercial_quay`), and a fishing harbour (:func:`build_fishing_harbour`)."""

from __future__ import annotations

import math

import numpy as np
import trimesh
from shapely.geometry import Polygon

from harborsight.sim.families._parts import _CAR_RGB, _gable, _local_to_vessel, _pick
from harborsight.sim.families.boats import add_barge, add_fishing_boat, add_tug
from harborsight.sim.layout import (
    _box,
    _Builder,
    _cylinder,
    _grey,
    _jitter,
    _try_add,
    add_quay_alongside,
    quay_face_offset,
)
from harborsight.sim.scene import OBSTACLE, Material, SceneObject

# port vehicles: hi-vis yellow and orange, and the cars' colours
_PORT_VEHICLE_RGB = [(0.75, 0.5, 0.01), (0.8, 0.25, 0.01), (0.6, 0.6, 0.62), (0.05, 0.15, 0.4),
                     (0.5, 0.03, 0.02)]
# work clothes seen from above: hi-vis vests, dark overalls, white and yellow helmets
_PERSON_RGB = [(0.85, 0.4, 0.01), (0.8, 0.75, 0.02), (0.05, 0.05, 0.08), (0.1, 0.15, 0.35),
               (0.8, 0.8, 0.78)]


def _port_vehicle(b: _Builder, kind: str, tag: str, deck_z: float) -> list[tuple[trimesh.Trimesh, str]]:
    """A truck (cab and a container trailer), a forklift, a reach stacker or a car, in its
    local frame (x forward), standing on ``deck_z``."""
    rng = b.rng
    body = b.material(f"{tag}-body", Material(_jitter(_pick(_PORT_VEHICLE_RGB if kind != "car"
                                                            else _CAR_RGB, rng), rng, 0.1), 0.4, 0.4, 0.05))
    dark = b.material(f"{tag}-dark", Material((0.03, 0.03, 0.035), 0.6, 0.2, 0.05))
    if kind == "truck":
        trailer_rgb = _pick([(0.5, 0.05, 0.02), (0.02, 0.12, 0.4), (0.05, 0.25, 0.06), (0.6, 0.6, 0.6)], rng)
        trailer = b.material(f"{tag}-trailer", Material(_jitter(trailer_rgb, rng), 0.5, 0.3, 0.2, 1.2))
        length = 12.19 if rng.random() < 0.6 else 6.06
        return [(_box(2.3, 2.5, 3.0, length / 2 + 1.4, 0.0, deck_z), body),
                (_box(length + 0.4, 2.5, 1.1, 0.0, 0.0, deck_z), dark),
                (_box(length, 2.44, 2.59, 0.0, 0.0, deck_z + 1.1), trailer)]
    if kind == "forklift":
        return [(_box(2.6, 1.2, 1.2, 0.0, 0.0, deck_z), body),
                (_box(1.0, 1.1, 1.0, -0.4, 0.0, deck_z + 1.2), dark),
                (_box(0.15, 1.0, 3.0, 1.4, 0.0, deck_z), dark)]
    if kind == "reach stacker":
        return [(_box(10.0, 4.0, 2.2, 0.0, 0.0, deck_z), body),
                (_box(2.0, 2.0, 2.0, -2.0, 0.0, deck_z + 2.2), dark),
                (_box(9.0, 0.8, 0.8, 4.0, 0.0, deck_z + 4.0), body)]
    return [(_box(4.5, 1.8, 0.8, 0.0, 0.0, deck_z + 0.2), body),      # a car
            (_box(2.4, 1.6, 0.6, -0.3, 0.0, deck_z + 1.0), body)]


# fish crates (blue, red, white, grey) and nets (green, orange, blue)
_CRATE_RGB = [(0.02, 0.1, 0.4), (0.5, 0.03, 0.02), (0.75, 0.75, 0.72), (0.3, 0.3, 0.3)]
_NET_RGB = [(0.03, 0.15, 0.05), (0.6, 0.2, 0.01), (0.03, 0.08, 0.3)]


def build_fishing_harbour(b: _Builder, hull: Polygon, hull_xy: np.ndarray, side: int,
                          gap_m: float) -> None:
    """The vessel alongside a fishing quay on ``side``: a low concrete quay with tyre fenders
    and bollards, fishing boats moored ahead and astern in rafts of one to three abreast, and
    on the quay a fish hall, stacks of fish crates, heaps of nets, vans and people."""
    rng = b.rng
    skew = float(rng.uniform(-3.0, 3.0))
    tyre = float(rng.uniform(0.25, 0.4))
    tan = math.tan(math.radians(skew))
    edge = quay_face_offset(hull_xy, side, gap_m, tyre, skew)
    along = (0.0 if side > 0 else 180.0) + skew
    height = float(rng.uniform(1.0, 2.2))
    concrete = b.material("quay-concrete", Material(_grey((0.35, 0.34, 0.32), rng, 0.3), 0.85, 0.0, 0.3, 0.3))
    xv, yv = _local_to_vessel((0.0, edge), along, 0.0, -30.0)
    b.add("quay", "quay", OBSTACLE, [(_box(400.0, 60.0, height + 3.0, 0.0, 0.0, -3.0), concrete)],
          xv, yv, along)
    rubber = b.material("quay-tyres", Material((0.012, 0.012, 0.012), 0.9, 0.0, 0.05))
    iron = b.material("quay-iron", Material(_jitter((0.05, 0.05, 0.06), rng), 0.5, 0.6, 0.1))
    for x in np.arange(-150.0 + rng.uniform(0, 4), 150.0, float(rng.uniform(2.5, 5.0))):
        xv, yv = _local_to_vessel((0.0, edge), along, float(x), tyre)
        b.add(f"quay-tyre{b.next_instance}", "fender", OBSTACLE,
              [(_cylinder(tyre, height + 0.4, 0.0, 0.0, -0.4, 8), rubber)], xv, yv, along)
    for x in np.arange(-150.0 + rng.uniform(0, 10), 150.0, float(rng.uniform(8.0, 15.0))):
        xv, yv = _local_to_vessel((0.0, edge), along, float(x), -0.8)
        b.add(f"quay-bollard{b.next_instance}", "bollard", OBSTACLE,
              [(_cylinder(0.22, 0.5, 0.0, 0.0, height, 8), iron)], xv, yv, along)
    x_min, x_max = float(hull_xy[:, 0].min()), float(hull_xy[:, 0].max())
    for direction in (1, -1):                     # rafts of fishing boats ahead and astern
        x = (x_max if direction > 0 else x_min) + direction * float(rng.uniform(3.0, 10.0))
        for _ in range(int(rng.integers(1, 4))):
            offset = 2 * tyre + 0.3
            for _ in range(int(rng.integers(1, 4))):          # abreast, outward from the face
                beam = 9.0                                      # about the widest drawn
                cx = x + direction * 14.0
                y = edge + cx * tan - side * (offset + beam / 2)
                boat = _try_add(b, lambda cx=cx, y=y: add_fishing_boat(
                    b, cx, y, skew + float(rng.choice([0.0, 180.0]))), 0.3)
                if boat is None:
                    break
                offset += beam + 0.4
            x += direction * float(rng.uniform(29.0, 36.0))
    hall = b.material("fish-hall", Material(_grey((0.55, 0.55, 0.55), rng, 0.3), 0.6, 0.3, 0.1, 0.8))
    xv, yv = _local_to_vessel((0.0, edge), along, float(rng.uniform(-60, 60)),
                              -float(rng.uniform(18, 35)))
    hall_box = _box(float(rng.uniform(25, 50)), float(rng.uniform(12, 20)), float(rng.uniform(5, 9)),
                    0, 0, height)
    b.add("fish-hall", "shed", OBSTACLE, [(hall_box, hall)], xv, yv, along)
    for _ in range(int(rng.integers(4, 14))):     # crates, nets, vans and people on the quay
        kind = str(rng.choice(["crates", "nets", "van", "person"], p=[0.35, 0.25, 0.15, 0.25]))
        tag = f"{kind}{b.next_instance}"
        if kind == "crates":
            mat = b.material(tag, Material(_jitter(_pick(_CRATE_RGB, rng), rng), 0.6))
            n = int(rng.integers(1, 7))
            parts = [(_box(1.2, 0.8, 0.3 * n, 0.0, 0.0, height), mat)]
        elif kind == "nets":
            mat = b.material(tag, Material(_jitter(_pick(_NET_RGB, rng), rng), 0.95, 0.0, 0.5, 3.0))
            parts = [(_gable(float(rng.uniform(2, 6)), float(rng.uniform(1.5, 3)),
                             float(rng.uniform(0.4, 1.2)), height), mat)]
        elif kind == "van":
            parts = _port_vehicle(b, "car", tag, height)
            parts[0] = (_box(5.2, 2.0, 1.9, 0.0, 0.0, height + 0.2), parts[0][1])
        else:
            mat = b.material(tag, Material(_jitter(_pick(_PERSON_RGB, rng), rng, 0.1), 0.8))
            parts = [(_cylinder(float(rng.uniform(0.2, 0.28)), float(rng.uniform(1.6, 1.9)),
                                0.0, 0.0, height, 8), mat)]
        x, y = float(rng.uniform(-70, 70)), -float(rng.uniform(1.5, 16.0))
        xv, yv = _local_to_vessel((0.0, edge), along, x, y)
        obj = b.add(tag, kind, OBSTACLE, parts, xv, yv, along + float(rng.uniform(0, 360)))
        if not _keeps_clear(obj, b.objects, 0.3):
            b.objects.remove(obj)


def _keeps_clear(new: SceneObject, objects: list, margin_m: float) -> bool:
    """Whether ``new`` keeps ``margin_m`` from everything placed before it except the quay
    slab it stands on."""
    fp = new.footprint()
    return all(fp.distance(o.footprint()) >= margin_m for o in objects
               if o is not new and o.kind != "quay")


def build_commercial_quay(b: _Builder, hull: Polygon, hull_xy: np.ndarray, side: int,
                          gap_m: float) -> None:
    """The vessel alongside a cargo quay on ``side`` (+1 starboard), its fenders ``gap_m`` off
    the hull: the quay of the classic scenarios (fenders, bollards, container stacks, a shed, a
    crane) with ships moored ahead and astern, at times a tug standing by off the vessel's other
    side and a barge along the face, and on the quay trucks with container trailers, forklifts,
    reach stackers, cars and people (all ``obstacle``), none overlapping."""
    rng = b.rng
    skew = float(rng.uniform(-2.0, 2.0))
    quay = add_quay_alongside(b, hull_xy, side, gap_m, skew, "quay", skip_ship=0.2,
                              ship_length_m=(20.0, 90.0), ship_spacing_m=(4.0, 30.0))
    edge, tan = quay.edge_m, math.tan(math.radians(skew))
    along = (0.0 if side > 0 else 180.0) + skew
    deck_z = float(np.asarray(quay.objects[0].parts[0].mesh.vertices)[:, 2].max())
    x_min, x_max = float(hull_xy[:, 0].min()), float(hull_xy[:, 0].max())
    fender = quay.fender_m
    if rng.random() < 0.5:                       # a tug standing by off the other side
        x = float(rng.uniform(x_min, x_max))
        far_side = float(hull_xy[:, 1].max() if side < 0 else -hull_xy[:, 1].min())
        y = -side * (far_side + gap_m + float(rng.uniform(3.0, 25.0)) + 7.0)
        _try_add(b, lambda x=x, y=y: add_tug(b, x, y, skew + float(rng.uniform(-30.0, 30.0))
                                             + float(rng.choice([0.0, 180.0]))), 1.0)
    if rng.random() < 0.5:                       # a barge along the face, ahead or astern
        direction = float(rng.choice([-1.0, 1.0]))
        x = (x_max if direction > 0 else x_min) + direction * float(rng.uniform(30.0, 90.0))
        y = edge + x * tan - side * (2 * fender + 0.3 + 7.0)
        _try_add(b, lambda x=x, y=y: add_barge(b, x, y, skew + float(rng.choice([0.0, 180.0]))), 1.0)
    for _ in range(int(rng.integers(3, 14))):    # vehicles, set back from the edge
        kind = str(rng.choice(["truck", "forklift", "reach stacker", "car"], p=[0.4, 0.25, 0.1, 0.25]))
        tag = f"{kind.replace(' ', '-')}{b.next_instance}"
        x, y = float(rng.uniform(-90, 90)), -float(rng.uniform(4.0, 45.0))
        xv, yv = _local_to_vessel((0.0, edge), along, x, y)
        heading = along + float(rng.choice([0.0, 90.0, 180.0, 270.0])) + float(rng.normal(0, 8))
        vehicle = b.add(tag, kind, OBSTACLE, _port_vehicle(b, kind, tag, deck_z), xv, yv, heading)
        if not _keeps_clear(vehicle, b.objects, 1.0):
            b.objects.remove(vehicle)
    for _ in range(int(rng.integers(2, 16))):    # people: on the quay, some near its edge
        tag = f"person{b.next_instance}"
        clothes = b.material(f"{tag}-clothes", Material(_jitter(_pick(_PERSON_RGB, rng), rng, 0.1), 0.8))
        tall = float(rng.uniform(1.6, 1.9))
        body = _cylinder(float(rng.uniform(0.2, 0.28)), tall, 0.0, 0.0, deck_z, 8)
        x = float(rng.uniform(-60, 60))
        y = -float(rng.uniform(1.2, 3.0) if rng.random() < 0.4 else rng.uniform(3.0, 30.0))
        xv, yv = _local_to_vessel((0.0, edge), along, x, y)
        person = b.add(tag, "person", OBSTACLE, [(body, clothes)], xv, yv, 0.0)
        if not _keeps_clear(person, b.objects, 0.3):
            b.objects.remove(person)
