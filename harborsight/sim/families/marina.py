"""A marina (:func:`build_marina`): rows of pontoons with finger piers full of moored boats
either side of the fairway, and frames that look along the berths."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from shapely.geometry import Polygon

from harborsight.sim.families._parts import _local_to_vessel, _overlaps_others, _planks
from harborsight.sim.families.boats import add_leisure_boat
from harborsight.sim.families.shore import add_shore
from harborsight.sim.layout import _box, _Builder, _grey
from harborsight.sim.scene import OBSTACLE, Material

#: marina pontoon decking: two weathered woods beside white and grey composite boards. The
#: marina tiles' pontoons are pale (median linear 0.54, p10-p90 0.29-0.81: as bright as the
#: boats, 0.47), where an all-wood palette (0.08-0.45) had taught "pale and flat is a boat"
_PONTOON_RGB = [(0.35, 0.3, 0.24), (0.45, 0.42, 0.38), (0.72, 0.72, 0.7), (0.6, 0.6, 0.57)]
#: the other pontoons: poured or precast concrete, pale as the tiles' are
_PONTOON_CONCRETE_RGB = (0.62, 0.61, 0.58)


@dataclass(frozen=True)
class MarinaLayout:
    """How full a marina is: the share of berths left empty, the rows of pontoons either side
    of the fairway (an integers' range) and a berth's pitch (share of its length, metres
    added)."""

    empty_berths: float
    rows_per_side: tuple[int, int]
    berth_pitch: tuple[float, float]


#: the real marina tiles are rows of moored boats: water 51 %, ship 30 % and 15 % undecided
#: (most of it boats and pontoons); the sparse marinas' renders at 120-150 m showed water
#: 76 %, ship 10 %. A berth is the widest boat's beam and a finger pier wide
DENSE_MARINA = MarinaLayout(empty_berths=0.05, rows_per_side=(3, 7), berth_pitch=(0.4, 1.0))
#: the marinas of datasets rendered before (``dense_marinas`` off)
SPARSE_MARINA = MarinaLayout(empty_berths=0.15, rows_per_side=(2, 5), berth_pitch=(0.45, 1.2))
#: share of marina frames whose camera looks along the berths, not at the vessel in the
#: fairway, and where such a frame aims across the rows on one side, in lanes (main pontoon
#: to main pontoon) from the middle of the nearest row's berths: at the moored boat nearest
#: that spot, if one is within a lane of it (a spot drawn alone fell past a row's end, on
#: the shore, in one view of three)
BERTH_VIEW_SHARE = 0.4
BERTH_VIEW_LANES = (0.0, 1.5)


class BerthView(NamedTuple):
    """A marina frame that looks along the berths: at the boat nearest a spot ``lanes`` out
    from the nearest row's berths; ``rng`` is the view's own stream, which the builder draws
    the side and the place along the rows from."""

    lanes: float
    rng: np.random.Generator


def draw_berth_view(rng: np.random.Generator) -> BerthView | None:
    """Whether a marina frame looks along the berths (:data:`BERTH_VIEW_SHARE`) and where, in
    lanes (:data:`BERTH_VIEW_LANES`), from the view's own stream ``rng``."""
    if rng.random() >= BERTH_VIEW_SHARE:
        return None
    return BerthView(float(rng.uniform(*BERTH_VIEW_LANES)), rng)


def add_pontoon_row(b: _Builder, origin_v: tuple[float, float], along_deg: float, length_m: float,
                    tag: str, berth_m: float, both_sides: bool, keep_out: Polygon,
                    layout: MarinaLayout = DENSE_MARINA) -> list[tuple[float, float]]:
    """A main pontoon along ``along_deg`` through ``origin_v`` with berths on its left (the
    fairway side; and on its right with ``both_sides``): boats side by side, bow or stern to
    the pontoon, a finger pier between every pair of berths and most single ones. Returns
    the centres (vessel frame) of the boats placed (none where the row did not fit)."""
    rng = b.rng
    deck = _planks(b, tag, _PONTOON_RGB) if rng.random() < 0.6 else b.material(
        f"{tag}-concrete", Material(_grey(_PONTOON_CONCRETE_RGB, rng, 0.25), 0.85, 0.0, 0.2, 1.0))
    width = rng.uniform(2.0, 3.0)
    z = rng.uniform(0.3, 0.6)
    pieces = [(_box(length_m, width, z + 0.4, 0.0, 0.0, -0.4), deck)]
    finger_len = berth_m * rng.uniform(0.55, 0.8)
    share, added_m = layout.berth_pitch
    pitch = share * berth_m + added_m              # a berth's width
    n_berths = int((length_m - 2.0) // pitch)
    boats = []
    for s in ((1, -1) if both_sides else (1,)):
        for j in range(n_berths + 1):
            x = -length_m / 2 + 1.0 + j * pitch
            if j % 2 == 0 or rng.random() < 0.5:
                finger = _box(0.8, finger_len, z + 0.4, x, s * (width / 2 + finger_len / 2), -0.4)
                pieces.append((finger, deck))
            if j < n_berths and rng.random() > layout.empty_berths:
                boat_l = float(np.clip(rng.normal(0.85 * berth_m, 0.12 * berth_m), 4.0, berth_m))
                boats.append((x + pitch / 2, s * (width / 2 + 0.4 + boat_l / 2), boat_l, s))
    row = b.add(f"{tag}-pontoon", "pontoon", OBSTACLE, pieces, *origin_v, along_deg)
    if row.footprint().intersects(keep_out) or _overlaps_others([row], b):
        b.objects.remove(row)
        return []
    placed = []
    for bx, by, bl, s in boats:
        xv, yv = _local_to_vessel(origin_v, along_deg, bx, by)
        heading = along_deg - 90.0 * s + float(rng.choice([0.0, 180.0], p=[0.6, 0.4]))
        boat = add_leisure_boat(b, xv, yv, heading, bl, "sail" if rng.random() < 0.35 else None)
        if boat.footprint().intersects(keep_out) or _overlaps_others([boat], b, margin_m=0.05):
            b.objects.remove(boat)
        else:
            placed.append((float(xv), float(yv)))
    return placed


def build_marina(b: _Builder, hull: Polygon, hull_xy: np.ndarray, side: int, gap_m: float) -> None:
    """The vessel of interest in a marina's fairway: rows of pontoons with boats moored stern
    or bow to the fairway on both sides, the nearest about ``gap_m`` from its hull on
    ``side``, and often a shore across the fairway's end."""
    rng = b.rng
    keep_out = b.objects[0].footprint().buffer(max(gap_m, 0.0) + 0.05)    # W, as footprints
    skew = float(rng.uniform(-5, 5))
    berth = float(rng.uniform(8.0, 16.0))
    lane = 2 * berth + rng.uniform(3.5, 7.0)      # main pontoon to main pontoon
    layout = DENSE_MARINA if b.dense_marinas else SPARSE_MARINA
    view = b.berth_view
    view_side = int(view.rng.choice([-1, 1])) if view is not None else 0
    view_spot, view_boats = None, []
    shore_x = float(hull_xy[:, 0].max()) + rng.uniform(40, 90) if rng.random() < 0.7 else None
    if shore_x is not None:
        add_shore(b, (shore_x, 0.0), -90.0 + skew, "shore")
    for s in (-1, 1):
        half_beam = float(hull_xy[:, 1].max() if s > 0 else -hull_xy[:, 1].min())
        g = gap_m if s == side else float(rng.uniform(4, 20))
        first_main = s * (half_beam + g + berth + 1.4)   # its boats' outer ends at about g
        along = skew if s > 0 else 180.0 + skew          # its left side faces the fairway
        if s == view_side:                                # a view along this side's berths
            view_spot = (float(view.rng.uniform(-30.0, 30.0)),
                         first_main - s * berth / 2 + s * view.lanes * lane)
        for k in range(int(rng.integers(*layout.rows_per_side))):
            x_c = float(rng.uniform(-40, 40))
            length = float(rng.uniform(80, 200))
            if shore_x is not None:                       # rows end short of the shore
                far_end = min(x_c + length / 2, shore_x - 8.0)
                length = far_end - (x_c - length / 2)
                x_c = far_end - length / 2
            if length > 20:
                boats = add_pontoon_row(b, (x_c, first_main + s * k * lane), along, length,
                                        f"row{b.next_instance}", berth,
                                        both_sides=k > 0 or rng.random() < 0.2,
                                        keep_out=keep_out, layout=layout)
                if s == view_side:
                    view_boats += boats
    if view_spot is not None:   # the boat nearest the spot, if one is within a lane of it
        def off_spot_m(centre: tuple[float, float]) -> float:
            return math.hypot(centre[0] - view_spot[0], centre[1] - view_spot[1])

        nearest = min(view_boats, default=view_spot, key=off_spot_m)
        b.aim_v = nearest if off_spot_m(nearest) <= lane else view_spot
