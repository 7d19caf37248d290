"""Parts the scene families share: palettes, convex primitives, and the placement rules
(nothing is placed over what came before it; what a family put nearer to the vessel than
its gap is dropped: the gap is the scene's nearest obstacle)."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from harborsight.sim.layout import _Builder, _jitter, convex_mesh
from harborsight.sim.scene import Material

_COVER_RGB = [(0.02, 0.08, 0.25), (0.55, 0.55, 0.52), (0.06, 0.12, 0.06), (0.35, 0.3, 0.2),
              (0.7, 0.7, 0.68), (0.25, 0.02, 0.02)]
_CAR_RGB = [(0.75, 0.75, 0.75), (0.02, 0.02, 0.02), (0.3, 0.3, 0.32), (0.4, 0.02, 0.02),
            (0.02, 0.08, 0.3), (0.6, 0.6, 0.62), (0.85, 0.85, 0.85)]


def _pick(palette: list, rng: np.random.Generator, p: np.ndarray | None = None):
    return palette[int(rng.choice(len(palette), p=p))]


def _gable(length: float, width: float, height: float, z_bottom: float) -> trimesh.Trimesh:
    """A gabled roof or canopy: a triangular prism along local x, ridge on the centreline."""
    points = [(x, y, z_bottom) for x in (-length / 2, length / 2) for y in (-width / 2, width / 2)]
    points += [(x, 0.0, z_bottom + height) for x in (-length / 2, length / 2)]
    return convex_mesh(np.array(points))


def _prism(outline_xy: np.ndarray, z_low: float, z_high: float,
           top_xy: np.ndarray | None = None) -> trimesh.Trimesh:
    """The convex solid between a convex outline at ``z_low`` and ``top_xy`` (the same
    outline when None, a smaller one for a bevel or a slope) at ``z_high``."""
    top_xy = outline_xy if top_xy is None else top_xy
    return convex_mesh(np.vstack((np.column_stack((outline_xy, np.full(len(outline_xy), z_low))),
                                  np.column_stack((top_xy, np.full(len(top_xy), z_high))))))


def _local_to_vessel(origin_v: tuple[float, float], along_deg: float, x: float, y: float
                     ) -> tuple[float, float]:
    """A point of a feature's local frame (x along ``along_deg`` from the bow, clockwise; y
    to its left) in the vessel frame (x bow, y starboard)."""
    a = math.radians(along_deg)
    return (origin_v[0] + x * math.cos(a) + y * math.sin(a),
            origin_v[1] + x * math.sin(a) - y * math.cos(a))


def _planks(b: _Builder, tag: str, palette: list):
    """A planked deck material in one of ``palette``'s colours (a lake-shore dock: wood in 4
    of 6 draws, white or grey composite boards in 2; a marina pontoon: :data:`_PONTOON_RGB`)."""
    rng = b.rng
    rgb = _pick(palette, rng)
    return b.material(f"{tag}-wood", Material(_jitter(rgb, rng, 0.2), 0.85, 0.0, 0.35, 3.0, pattern="planks"))


_GROUND = ("land", "riprap", "tree", "road", "house", "car")


class PlacedBounds:
    """The footprint bounds of a builder's objects as arrays, kept in step with its list.

    Objects are appended and now and then removed (mostly the last ones), so each call
    keeps the cached rows of the list's unchanged head, found by object identity, and adds
    the rest. The cache holds the objects themselves: an id it holds cannot be reused by a
    new object. A marina has hundreds of objects and checks each new boat against them.
    """

    def __init__(self) -> None:
        self.objects: list = []
        self.ids = np.empty(0, np.int64)
        self.bounds = np.empty((0, 4))
        self.ground = np.empty(0, bool)          # a kind in _GROUND (docks may start there)
        self.vessel = np.empty(0, bool)          # the vessel of interest (its gap is apart)

    def sync(self, objects: list) -> None:
        ids = np.fromiter(map(id, objects), np.int64, len(objects))
        m = min(len(ids), len(self.ids))
        changed = np.flatnonzero(ids[:m] != self.ids[:m])
        keep = int(changed[0]) if len(changed) else m
        tail = objects[keep:]
        self.objects = self.objects[:keep] + tail
        self.ids = ids
        self.bounds = np.vstack((self.bounds[:keep], np.array([_bounds(o) for o in tail]).reshape(-1, 4)))
        self.ground = np.concatenate((self.ground[:keep], np.array([o.kind in _GROUND for o in tail], bool)))
        self.vessel = np.concatenate((self.vessel[:keep], np.array([o.instance_id == 1 for o in tail], bool)))


def _overlaps_others(new: list, b: _Builder, margin_m: float = 0.0) -> bool:
    """Whether an object of ``new`` comes within ``margin_m`` of an object of ``b`` placed
    before them (the vessel of interest aside: its gap is kept apart). Docks and pontoons
    may start on land, so what stands there counts against boats only. Bounding boxes first
    (:class:`PlacedBounds`), then the footprints' distance."""
    index = b.__dict__.setdefault("placed_bounds", PlacedBounds())
    index.sync(b.objects)
    earlier = ~index.vessel & ~np.isin(index.ids, np.fromiter(map(id, new), np.int64, len(new)))
    if not earlier.any():
        return False
    bounds = index.bounds
    for n in new:
        fp = n.footprint()
        x0, y0, x1, y1 = _bounds(n)
        near = (earlier & (bounds[:, 0] <= x1 + margin_m) & (bounds[:, 2] >= x0 - margin_m)
                & (bounds[:, 1] <= y1 + margin_m) & (bounds[:, 3] >= y0 - margin_m))
        if n.kind != "boat":
            near &= ~index.ground
        if any(fp.distance(index.objects[k].footprint()) <= margin_m for k in np.flatnonzero(near)):
            return True
    return False


def _bounds(obj) -> tuple[float, float, float, float]:
    """An object's footprint bounds, kept on it (objects do not move once placed)."""
    if "_bounds" not in obj.__dict__:
        obj.__dict__["_bounds"] = obj.footprint().bounds
    return obj.__dict__["_bounds"]


def keep_gap(b: _Builder, gap_m: float) -> None:
    """Drop what a family placed nearer to the vessel than ``gap_m`` (a tree crown over the
    water, a rip-rap stone): the scene's gap is its nearest obstacle."""
    vessel_fp = b.objects[0].footprint()
    b.objects[1:] = [o for o in b.objects[1:] if o.footprint().distance(vessel_fp) >= gap_m]
