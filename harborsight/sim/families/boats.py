"""The families' vessels: leisure craft (motor, sail, covered, pontoon, RIB, yacht, jet ski)
with their colours from real-world shares, tugs, barges and fishing boats, and small craft
under way."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import trimesh
from shapely.geometry import MultiPoint, Polygon

from harborsight.sim.families._parts import _COVER_RGB, _gable, _overlaps_others, _pick, _prism
from harborsight.sim.layout import (
    HullRanges,
    _box,
    _Builder,
    _cylinder,
    _jitter,
    _ship_parts,
    random_hull_parameters,
    unit_cylinder,
)
from harborsight.sim.scene import SHIP, Material, SceneObject
from harborsight.vessel.hullgen import HullParameters, generate_hull_mesh

# Leisure hulls are mostly white; then navy, red, dark green, grey, black, cream (a rough
# share from marina photos, not a survey)
_LEISURE_HULL_RGB = [(0.78, 0.78, 0.76), (0.8, 0.8, 0.8), (0.72, 0.74, 0.76), (0.03, 0.06, 0.2),
                     (0.4, 0.03, 0.03), (0.02, 0.12, 0.05), (0.35, 0.36, 0.38), (0.02, 0.02, 0.02),
                     (0.7, 0.62, 0.45)]
_LEISURE_HULL_P = np.array([0.28, 0.2, 0.15, 0.09, 0.07, 0.05, 0.07, 0.04, 0.05])
#: a quarter turn about y: local z to x
_TURN_Z_TO_X = trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0))


def _rotated_cylinder_x(radius: float, length: float, x: float, y: float, z: float) -> trimesh.Trimesh:
    """A cylinder lying along local x, centred at (x, y, z)."""
    unit = unit_cylinder(10)
    vertices = trimesh.transformations.transform_points(unit.vertices * np.array([radius, radius, length]),
                                                        _TURN_Z_TO_X)
    vertices += (x, y, z)
    return trimesh.Trimesh(vertices, unit.faces.copy(), process=False)


#: small craft: beamier than ships, with a low cabin
LEISURE_HULLS = HullRanges(beam=(0.3, 0.4), deckhouse_start=(0.3, 0.5), draft_share=0.06,
                           draft_min_m=0.3, freeboard=(0.07, 0.11), freeboard_limits_m=(0.5, 2.2),
                           bow_fraction=(0.3, 0.45), flare=(0.0, 0.12), deckhouse_width=(0.5, 0.8),
                           deckhouse_height=(0.05, 0.12), deckhouse_height_limits_m=(0.4, 3.0))
_TEMPLATE_LENGTH_M = 10.0
_N_TEMPLATES = 6


def _hull_template(b: _Builder, length_m: float) -> tuple[HullParameters, list[trimesh.Trimesh]]:
    """A leisure hull of ``length_m`` (hull first, then the cabin; centred on midship),
    scaled from one of a few shapes drawn once per scene: a marina has hundreds of boats and
    a hull takes milliseconds to build."""
    templates = b.__dict__.setdefault("leisure_hulls", [])
    if len(templates) < _N_TEMPLATES:
        params = random_hull_parameters(b.rng, _TEMPLATE_LENGTH_M, LEISURE_HULLS)
        pieces = sorted(generate_hull_mesh(params).split(only_watertight=False), key=lambda m: -m.extents[0])
        for piece in pieces:
            piece.apply_translation((-_TEMPLATE_LENGTH_M / 2, 0.0, 0.0))
        templates.append((params, pieces))
        params, pieces = templates[-1]
    else:
        params, pieces = templates[int(b.rng.integers(len(templates)))]
    k = length_m / _TEMPLATE_LENGTH_M
    scaled = [trimesh.Trimesh(piece.vertices * k, piece.faces.copy(), process=False) for piece in pieces]
    return replace(params, length_m=length_m, beam_m=params.beam_m * k, draft_m=params.draft_m * k,
                   freeboard_m=params.freeboard_m * k,
                   deckhouse=(*params.deckhouse[:3], params.deckhouse[3] * k)), scaled


#: the kinds of small craft a boat is drawn from, and their shares; a motor yacht only where
#: a boat is at least :data:`_YACHT_MIN_LENGTH_M` long (its share then goes to the others)
_BOAT_KINDS = ("motor", "sail", "covered", "pontoon", "rib", "yacht")
_BOAT_KIND_P = np.array([0.32, 0.22, 0.16, 0.12, 0.12, 0.06])
_YACHT_MIN_LENGTH_M = 11.0
#: RIB tube colours (grey, black, orange, red, dark blue; grey the most common) and shares
_RIB_TUBE_RGB = [(0.32, 0.33, 0.34), (0.03, 0.03, 0.03), (0.8, 0.25, 0.02), (0.45, 0.03, 0.02),
                 (0.03, 0.06, 0.2)]
_RIB_TUBE_P = np.array([0.45, 0.2, 0.15, 0.1, 0.1])


def _draw_boat_kind(rng: np.random.Generator, length_m: float) -> str:
    p = _BOAT_KIND_P.copy()
    if length_m < _YACHT_MIN_LENGTH_M:
        p[_BOAT_KINDS.index("yacht")] = 0.0
    return str(rng.choice(_BOAT_KINDS, p=p / p.sum()))


def _rib_parts(b: _Builder, tag: str, length_m: float, hull_mat: str, deck_mat: str
               ) -> list[tuple[trimesh.Trimesh, str]]:
    """A rigid inflatable boat: a tube collar round a flat deck (square stern, round bow), a
    centre console, now and then a T-top, and one or two outboards.

    From above a collar is a band of tube round the deck, shaded like a tube: it is drawn as
    a convex slab of the boat's outline in the tube's colour, bevelled inward by half the
    tube's radius at its top, with the deck a thin convex slab inset by the tube's diameter
    and lying 2 cm above it. Four or five parts, as few as a motor boat's: a marina holds
    hundreds of boats, and each part costs layout and render time."""
    rng = b.rng
    beam = length_m * rng.uniform(0.36, 0.42)
    tube_r = float(np.clip(0.055 * length_m, 0.22, 0.32))
    tube = b.material(f"{tag}-tube", Material(_jitter(_pick(_RIB_TUBE_RGB, rng, _RIB_TUBE_P), rng, 0.08),
                                              0.55, 0.0, 0.06))

    def outline(inset_m: float) -> np.ndarray:
        """The boat's outline ``inset_m`` inside its edge: square at the stern, the bow a
        half ellipse over the forward quarter."""
        half_w = beam / 2 - inset_m
        stern_x = -length_m / 2 + inset_m
        shoulder_x = length_m * 0.25
        bow_l = length_m / 2 - inset_m - shoulder_x
        angles = np.linspace(-math.pi / 2, math.pi / 2, 9)
        bow = np.column_stack((shoulder_x + bow_l * np.cos(angles), half_w * np.sin(angles)))
        return np.vstack(([[stern_x, -half_w]], bow, [[stern_x, half_w]]))

    collar_top = 1.6 * tube_r
    parts = [(_prism(outline(0.0), -0.2, collar_top, outline(0.5 * tube_r)), tube),
             (_prism(outline(2 * tube_r), collar_top, collar_top + 0.02), deck_mat)]
    console_x = -0.05 * length_m
    deck_w = beam - 4 * tube_r
    parts.append((_box(0.7, min(0.8, deck_w * 0.5), 1.0, console_x, 0.0, collar_top), hull_mat))
    if rng.random() < 0.35 and length_m > 6:
        frame = b.material(f"{tag}-ttop", Material((0.7, 0.7, 0.72), 0.3, 0.8, 0.02))
        parts.append((_box(1.8, deck_w * 0.8, 0.08, console_x, 0.0, collar_top + 1.9), frame))
    engine = b.material(f"{tag}-engine", Material(_pick([(0.02, 0.02, 0.02), (0.75, 0.75, 0.75)], rng),
                                                  0.4, 0.1, 0.03))
    engines_w = 1.0 if length_m > 7.5 else 0.4          # twin outboards side by side, or one
    parts.append((_box(0.45, engines_w, 0.9, -length_m / 2 + 0.25, 0.0, -0.2), engine))
    return parts


def _yacht_parts(b: _Builder, tag: str, params: HullParameters, length_m: float
                 ) -> list[tuple[trimesh.Trimesh, str]]:
    """A motor yacht's upper works on a leisure hull: a saloon deckhouse, a flybridge with a
    helm and often a hardtop, and a teak or white sun deck aft."""
    rng = b.rng
    top = params.freeboard_m
    beam = params.beam_m
    white = b.material(f"{tag}-super", Material(_jitter((0.82, 0.82, 0.8), rng, 0.04), 0.35, 0.0, 0.03))
    saloon_l = length_m * rng.uniform(0.42, 0.55)
    saloon_x = length_m * rng.uniform(-0.05, 0.08)
    saloon_h = rng.uniform(1.9, 2.4)
    parts = [(_box(saloon_l, beam * 0.8, saloon_h, saloon_x, 0.0, top), white)]
    fly_l = saloon_l * rng.uniform(0.55, 0.8)
    fly_x = saloon_x - (saloon_l - fly_l) / 2 * rng.uniform(0.0, 1.0)
    parts.append((_box(fly_l, beam * 0.72, 0.9, fly_x, 0.0, top + saloon_h), white))
    if rng.random() < 0.6:
        roof = b.material(f"{tag}-hardtop", Material(_pick([(0.82, 0.82, 0.8), (0.05, 0.05, 0.06)], rng),
                                                     0.4, 0.0, 0.03))
        parts.append((_box(fly_l * 0.6, beam * 0.7, 0.1, fly_x, 0.0, top + saloon_h + 2.1), roof))
    teak = (0.45, 0.3, 0.16) if rng.random() < 0.6 else (0.8, 0.8, 0.78)
    deck = b.material(f"{tag}-sundeck", Material(_jitter(teak, rng, 0.08), 0.7, 0.0, 0.12, 3.0))
    aft_l = length_m * 0.5 - (saloon_l / 2 - saloon_x) - 0.5
    if aft_l > 0.8:
        parts.append((_box(aft_l, beam * 0.85, 0.05, -length_m / 2 + 0.3 + aft_l / 2, 0.0, top), deck))
    return parts


def paint_leisure_vessel(b: _Builder, rng: np.random.Generator) -> None:
    """Repaint the vessel of interest (:func:`~harborsight.sim.layout._vessel_object`'s
    materials) as a leisure craft, with draws from ``rng``: a hull from
    :data:`_LEISURE_HULL_RGB`, its deckhouse white, cream or light grey, or now and then a
    canvas top (navy, grey, tan)."""
    b.material("vessel-hull", Material(_jitter(_pick(_LEISURE_HULL_RGB, rng, _LEISURE_HULL_P), rng, 0.08),
                                       rng.uniform(0.25, 0.6), 0.0, 0.08))
    if rng.random() < 0.8:
        house_rgb = _pick([(0.8, 0.8, 0.78), (0.75, 0.72, 0.64), (0.62, 0.63, 0.64)], rng)
    else:
        house_rgb = _pick(_COVER_RGB, rng)
    b.material("vessel-house", Material(_jitter(house_rgb, rng, 0.06), 0.45, 0.0, 0.05))


def add_leisure_boat(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float,
                     length_m: float, kind: str | None = None):
    """A moored or lifted small craft centred at (x_v, y_v): motor boat, sailing boat (mast),
    covered boat (a tarp over the deck), pontoon boat (two tubes, a flat deck and a bimini),
    RIB (a tube collar, a console, outboards), motor yacht (11 m and longer: a saloon and a
    flybridge) or jet ski. Colours follow :data:`_LEISURE_HULL_RGB`."""
    rng = b.rng
    kind = kind or _draw_boat_kind(rng, length_m)
    tag = f"{kind}{b.next_instance}"
    hull_mat = b.material(f"{tag}-hull", Material(_jitter(_pick(_LEISURE_HULL_RGB, rng, _LEISURE_HULL_P),
                                                          rng, 0.08), rng.uniform(0.25, 0.6), 0.0, 0.08))
    deck_rgb = (0.75, 0.74, 0.7) if rng.random() < 0.6 else (0.45, 0.33, 0.2)
    deck_mat = b.material(f"{tag}-deck", Material(_jitter(deck_rgb, rng, 0.1), 0.7, 0.0, 0.15, 2.0))
    parts: list[tuple[trimesh.Trimesh, str]] = []
    if kind == "pontoon":
        width = length_m * rng.uniform(0.3, 0.36)
        for side in (-1, 1):
            parts.append((_rotated_cylinder_x(0.3, length_m * 0.95, 0.0, side * (width / 2 - 0.35), 0.05),
                          hull_mat))
        parts.append((_box(length_m, width, 0.25, 0.0, 0.0, 0.35), deck_mat))
        if rng.random() < 0.7:
            bimini = b.material(f"{tag}-bimini", Material(_jitter(_pick(_COVER_RGB, rng), rng), 0.8))
            parts.append((_box(length_m * 0.4, width * 0.95, 0.05, -0.05 * length_m, 0.0, 2.0), bimini))
        return b.add(tag, "boat", SHIP, parts, x_v, y_v, rel_heading_deg)
    if kind == "jetski":
        length_m = min(length_m, 3.5)
        parts.append((_box(length_m, 1.2, 0.7, 0.0, 0.0, -0.2), hull_mat))
        parts.append((_box(length_m * 0.35, 0.4, 0.35, -0.1 * length_m, 0.0, 0.5), deck_mat))
        return b.add(tag, "boat", SHIP, parts, x_v, y_v, rel_heading_deg)
    if kind == "rib":
        return b.add(tag, "boat", SHIP, _rib_parts(b, tag, length_m, hull_mat, deck_mat),
                     x_v, y_v, rel_heading_deg)
    params, pieces = _hull_template(b, length_m)
    if kind == "yacht":         # the hull alone: the yacht's own upper works replace the cabin
        parts.append((pieces[0], hull_mat))
        parts += _yacht_parts(b, tag, params, length_m)
        return b.add(tag, "boat", SHIP, parts, x_v, y_v, rel_heading_deg)
    for i, piece in enumerate(pieces):
        parts.append((piece, hull_mat if i == 0 else deck_mat))
    top = params.freeboard_m
    if kind == "covered":
        cover = b.material(f"{tag}-cover", Material(_jitter(_pick(_COVER_RGB, rng), rng),
                                                    0.85, 0.0, 0.2, 1.0))
        parts.append((_gable(length_m * 0.8, params.beam_m * 0.85, 0.4 + 0.3 * rng.random(),
                             top + params.deckhouse[3] * 0.5), cover))
    elif kind == "sail":
        mast_h = length_m * rng.uniform(1.1, 1.5)
        metal = b.material(f"{tag}-mast", Material((0.6, 0.6, 0.62), 0.3, 0.8, 0.02))
        x_mast = (0.55 - 0.5) * length_m
        parts.append((_cylinder(0.06 + 0.004 * length_m, mast_h, x_mast, 0.0, top), metal))
        parts.append((_rotated_cylinder_x(0.05, length_m * 0.4, x_mast - length_m * 0.2, 0.0, top + 1.2),
                      metal))
    return b.add(tag, "boat", SHIP, parts, x_v, y_v, rel_heading_deg)


def add_tug(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float) -> SceneObject:
    """A harbour tug centred at (x_v, y_v): a short beamy hull (22-32 m, beam 0.36-0.42 of the
    length), a tall wheelhouse amidships and a belt of black tyre fenders along the hull's deck
    edge (part of the ship)."""
    rng = b.rng
    length = float(rng.uniform(22.0, 32.0))
    start = float(rng.uniform(0.4, 0.55))
    params = HullParameters(
        length_m=length, beam_m=length * float(rng.uniform(0.36, 0.42)),
        draft_m=float(rng.uniform(3.0, 5.0)), freeboard_m=float(rng.uniform(1.8, 2.6)),
        bow_fraction=float(rng.uniform(0.3, 0.45)), flare=float(rng.uniform(0.05, 0.12)),
        deckhouse=(start, start + float(rng.uniform(0.18, 0.25)), float(rng.uniform(0.5, 0.65)),
                   float(rng.uniform(5.0, 8.0))))
    tag = f"tug{b.next_instance}"
    parts = _ship_parts(b, params, tag)
    rubber = b.material(f"{tag}-tyres", Material((0.012, 0.012, 0.012), 0.9, 0.0, 0.05))
    hull = parts[0][0]
    top = hull.vertices[hull.vertices[:, 2] >= hull.vertices[:, 2].max() - 1e-6]
    ring = MultiPoint(top[:, :2]).convex_hull.exterior
    for d in np.arange(0.0, ring.length, float(rng.uniform(1.0, 1.6))):
        p = ring.interpolate(float(d))
        parts.append((_cylinder(0.35, 0.6, p.x, p.y, params.freeboard_m - 0.7, 8), rubber))
    return b.add(tag, "tug", SHIP, parts, x_v, y_v, rel_heading_deg)


def add_barge(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float) -> SceneObject:
    """A dumb barge centred at (x_v, y_v): a box hull 30-70 m long (beam a fifth of it, at
    least 8 m), a hatch coaming over its hold, and a heap of sand, gravel or coal on it in half
    of them."""
    rng = b.rng
    length = float(rng.uniform(30.0, 70.0))
    beam = max(8.0, length * float(rng.uniform(0.17, 0.24)))
    freeboard = float(rng.uniform(1.2, 3.0))
    tag = f"barge{b.next_instance}"
    steel = b.material(f"{tag}-hull", Material(_jitter(_pick([(0.2, 0.07, 0.03), (0.02, 0.02, 0.02),
                                                              (0.05, 0.1, 0.2), (0.3, 0.28, 0.25)], rng),
                                                       rng), 0.6, 0.3, 0.3, 0.4))
    coaming = b.material(f"{tag}-coaming", Material(_jitter((0.12, 0.12, 0.12), rng), 0.6, 0.3, 0.2))
    parts = [(_box(length, beam, freeboard + 2.0, 0.0, 0.0, -2.0), steel),
             (_box(length * 0.82, beam - 1.6, 0.5, 0.0, 0.0, freeboard), coaming)]
    if rng.random() < 0.5:
        cargo_rgb = _pick([(0.45, 0.36, 0.22), (0.3, 0.3, 0.3), (0.03, 0.03, 0.03)], rng)
        cargo = b.material(f"{tag}-cargo", Material(_jitter(cargo_rgb, rng), 0.95, 0.0, 0.4, 2.0))
        parts.append((_gable(length * 0.75, beam - 2.0, float(rng.uniform(1.0, 3.0)),
                             freeboard + 0.5), cargo))
    return b.add(tag, "barge", SHIP, parts, x_v, y_v, rel_heading_deg)


#: fishing boats: beamy, the wheelhouse forward, a high freeboard for their size
FISHING_HULLS = HullRanges(beam=(0.28, 0.36), deckhouse_start=(0.55, 0.66), freeboard=(0.07, 0.1),
                           freeboard_limits_m=(0.9, 2.5), deckhouse_width=(0.5, 0.7),
                           deckhouse_height=(0.12, 0.2), deckhouse_height_limits_m=(2.0, 4.0))
_FISHING_HULL_RGB = [(0.02, 0.08, 0.3), (0.4, 0.03, 0.02), (0.03, 0.15, 0.05), (0.7, 0.7, 0.68),
                     (0.02, 0.02, 0.02), (0.05, 0.25, 0.35)]


def add_fishing_boat(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float) -> SceneObject:
    """A fishing boat (10-28 m) centred at (x_v, y_v): a beamy hull, the wheelhouse forward, a
    gantry over the stern and, on half of them, outrigger booms swung out to both sides."""
    rng = b.rng
    params = random_hull_parameters(rng, float(rng.uniform(10.0, 28.0)), FISHING_HULLS)
    tag = f"fishing{b.next_instance}"
    parts = _ship_parts(b, params, tag)
    parts[0] = (parts[0][0], b.material(f"{tag}-hull", Material(
        _jitter(_pick(_FISHING_HULL_RGB, rng), rng), float(rng.uniform(0.3, 0.6)), 0.1, 0.12)))
    gantry_rgb = _pick([(0.7, 0.7, 0.68), (0.6, 0.35, 0.01), (0.02, 0.02, 0.02)], rng)
    steel = b.material(f"{tag}-gantry", Material(_jitter(gantry_rgb, rng), 0.5, 0.5, 0.05))
    length, half = params.length_m, 0.5 * params.beam_m
    top, tall = params.freeboard_m, float(rng.uniform(3.0, 5.0))
    stern = -length / 2 + 0.8
    parts += [(_box(0.3, 0.3, tall, stern, s * (half - 0.5), top), steel) for s in (-1, 1)]
    parts.append((_box(0.35, 2 * half - 0.7, 0.35, stern, 0.0, top + tall), steel))
    if rng.random() < 0.5:
        reach = half + float(rng.uniform(3.0, 7.0))
        x_mast = (params.deckhouse[0] - 0.5) * length - 1.0
        parts += [(_box(0.25, reach, 0.25, x_mast, s * reach / 2, top + tall * 0.8), steel)
                  for s in (-1, 1)]
    return b.add(tag, "fishing boat", SHIP, parts, x_v, y_v, rel_heading_deg)


def add_boats_under_way(b: _Builder, hull: Polygon, count: int, gap_m: float) -> None:
    """``count`` small craft in open water 8-80 m off the vessel (``hull``: its outline in
    the vessel frame), any heading, marked with their course (their wakes are painted on the
    render); dropped where they would touch something or come nearer to the vessel than
    ``gap_m``."""
    rng = b.rng
    vessel_fp = b.objects[0].footprint()
    for _ in range(count):
        ring = hull.buffer(rng.uniform(8.0, 80.0), quad_segs=8).exterior
        p = ring.interpolate(rng.uniform(0, 1), normalized=True)
        rel_heading = float(rng.uniform(0, 360))
        boat = add_leisure_boat(b, p.x, p.y, rel_heading, float(rng.uniform(3.5, 9.0)),
                                "jetski" if rng.random() < 0.2 else None)
        boat.course_deg = (b.heading_deg + rel_heading) % 360.0      # the bow's bearing
        if (_overlaps_others([boat], b, margin_m=1.0)
                or boat.footprint().distance(vessel_fp) < gap_m):
            b.objects.remove(boat)
