"""Scene families that look like real harbours (issue #26): a lake or river shore with private
docks and boat lifts, a marina with rows of pontoons and finger piers full of moored boats,
a commercial quay with its vehicles and people, and a fishing harbour.

They sit beside the five classic scenarios of :mod:`harborsight.sim.layout` and use its
builder, so the same rules hold: every part is a convex mesh in the world frame W, vessels are
``ship`` (1), everything solid that is not a vessel is ``obstacle`` (2): land, lawns, trees,
houses, cars, rip-rap, docks, pontoons, lift frames and canopies, port vehicles and people.
Boats sitting on a lift are ``ship``; seen from above under a canopy they are hidden by it,
as in the real photos.

Each family also draws its own look (:func:`sample_realistic_environment`): brown, green or
blue water of any turbidity, a consumer drone's camera (vignetting, white balance, JPEG, a
little motion blur), on top of the classic sun, sky, waves and haze. The classic scenarios
keep their draws, so datasets rendered before these families are reproduced exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import trimesh
from shapely.geometry import MultiPoint, Polygon

from harborsight.sim.layout import (
    OBSTACLE,
    SHIP,
    Environment,
    HullRanges,
    Material,
    SceneObject,
    _box,
    _Builder,
    _cylinder,
    _grey,
    _jitter,
    _ship_parts,
    _try_add,
    add_quay_alongside,
    convex_mesh,
    quay_face_offset,
    random_hull_parameters,
    sample_environment,
    unit_cylinder,
)
from harborsight.vessel.hullgen import HullParameters, generate_hull_mesh

# Leisure hulls are mostly white; then navy, red, dark green, grey, black, cream (a rough
# share from marina photos, not a survey)
_LEISURE_HULL_RGB = [(0.78, 0.78, 0.76), (0.8, 0.8, 0.8), (0.72, 0.74, 0.76), (0.03, 0.06, 0.2),
                     (0.4, 0.03, 0.03), (0.02, 0.12, 0.05), (0.35, 0.36, 0.38), (0.02, 0.02, 0.02),
                     (0.7, 0.62, 0.45)]
_LEISURE_HULL_P = np.array([0.28, 0.2, 0.15, 0.09, 0.07, 0.05, 0.07, 0.04, 0.05])
_COVER_RGB = [(0.02, 0.08, 0.25), (0.55, 0.55, 0.52), (0.06, 0.12, 0.06), (0.35, 0.3, 0.2),
              (0.7, 0.7, 0.68), (0.25, 0.02, 0.02)]
_CAR_RGB = [(0.75, 0.75, 0.75), (0.02, 0.02, 0.02), (0.3, 0.3, 0.32), (0.4, 0.02, 0.02),
            (0.02, 0.08, 0.3), (0.6, 0.6, 0.62), (0.85, 0.85, 0.85)]
_ROOF_RGB = [(0.15, 0.15, 0.16), (0.3, 0.08, 0.05), (0.4, 0.4, 0.4), (0.12, 0.14, 0.2),
             (0.35, 0.3, 0.25)]
# water from clear blue over green to brown lake water (linear RGB, as the classic palette)
_REAL_WATER_RGB = [(0.01, 0.035, 0.07), (0.02, 0.06, 0.08), (0.03, 0.07, 0.04), (0.04, 0.06, 0.03),
                   (0.06, 0.05, 0.025), (0.045, 0.045, 0.03), (0.02, 0.04, 0.035),
                   (0.05, 0.07, 0.06)]
# turbid lake and river water, tan to olive (the lake-shore photos' water is about sRGB
# (150, 125, 90): linear (0.30, 0.20, 0.10)); drawn for most lake shores
_TURBID_WATER_RGB = [(0.26, 0.18, 0.09), (0.2, 0.16, 0.08), (0.16, 0.15, 0.08), (0.12, 0.12, 0.07),
                     (0.22, 0.2, 0.12), (0.09, 0.1, 0.06)]


def _pick(palette: list, rng: np.random.Generator, p: np.ndarray | None = None):
    return palette[int(rng.choice(len(palette), p=p))]


#: a quarter turn about y: local z to x
_TURN_Z_TO_X = trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0))
_UNIT_SPHERE = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
#: a crown's lobes are rounder (320 faces, not 80): their facets showed at 40 m
_LOBE_SPHERE = trimesh.creation.icosphere(subdivisions=2, radius=1.0)


def _rotated_cylinder_x(radius: float, length: float, x: float, y: float, z: float) -> trimesh.Trimesh:
    """A cylinder lying along local x, centred at (x, y, z)."""
    unit = unit_cylinder(10)
    vertices = trimesh.transformations.transform_points(unit.vertices * np.array([radius, radius, length]),
                                                        _TURN_Z_TO_X)
    vertices += (x, y, z)
    return trimesh.Trimesh(vertices, unit.faces.copy(), process=False)


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


def _ellipsoid(radius_xy: float, radius_z: float, z_centre: float, x: float = 0.0,
               y: float = 0.0, unit: trimesh.Trimesh = _UNIT_SPHERE) -> trimesh.Trimesh:
    vertices = unit.vertices * np.array([radius_xy, radius_xy, radius_z])
    vertices += (x, y, z_centre)
    return trimesh.Trimesh(vertices, unit.faces.copy(), process=False)


def _crown_lobes(radius_m: float, z_centre: float, rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """A tree's crown as real canopy looks from above: a lumpy mass of leaf clusters, not one
    smooth ellipsoid. A central lobe of 0.6-0.75 r and 4-7 lobes of 0.35-0.55 r around it,
    their centres 0.3-0.6 r out at evenly spread bearings (jittered) and from 0.3 r lower to
    0.15 r higher, each flattened to 0.6-0.9 of its radius. Every lobe is convex (the
    scene's rule); together they stay within about 1.15 r of the trunk. Their own shading
    and the shadows they cast on each other give the crown its clumps."""
    lobes = [_ellipsoid(radius_m * rng.uniform(0.6, 0.75), radius_m * rng.uniform(0.45, 0.6),
                        z_centre, unit=_LOBE_SPHERE)]
    n = int(rng.integers(4, 8))
    start = rng.uniform(0.0, 2 * math.pi)
    for k in range(n):
        bearing = start + 2 * math.pi * k / n + rng.uniform(-0.35, 0.35)
        out = radius_m * rng.uniform(0.3, 0.6)
        lobe_r = radius_m * rng.uniform(0.35, 0.55)
        lobes.append(_ellipsoid(lobe_r, lobe_r * rng.uniform(0.6, 0.9),
                                z_centre + radius_m * rng.uniform(-0.3, 0.15),
                                out * math.cos(bearing), out * math.sin(bearing), _LOBE_SPHERE))
    return lobes


# ------------------------------------------------------------------------ boats


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


# ------------------------------------------------------------------------ the shore


def _local_to_vessel(origin_v: tuple[float, float], along_deg: float, x: float, y: float
                     ) -> tuple[float, float]:
    """A point of a feature's local frame (x along ``along_deg`` from the bow, clockwise; y
    to its left) in the vessel frame (x bow, y starboard)."""
    a = math.radians(along_deg)
    return (origin_v[0] + x * math.cos(a) + y * math.sin(a),
            origin_v[1] + x * math.sin(a) - y * math.cos(a))


def add_shore(b: _Builder, origin_v: tuple[float, float], along_deg: float, tag: str,
              length_m: float = 360.0, depth_m: float = 140.0, wooded_share: float = 0.0):
    """Land whose waterline runs through ``origin_v`` along ``along_deg`` (water on the left
    of that direction, land on the right), with a wavy edge, a lawn, a rip-rap or sand band,
    trees (some over the water), houses, a road and cars; with probability ``wooded_share``
    woods over the land behind the waterline (:func:`_add_woods`; no draw at 0). Returns the
    waterline as a function of the local x (along the shore; local y toward the water), for
    docks to start from."""
    rng = b.rng
    height = rng.uniform(0.4, 1.6)
    lawn = b.material(f"{tag}-lawn", Material(
        _jitter(_pick([(0.07, 0.14, 0.03), (0.12, 0.2, 0.04), (0.1, 0.16, 0.05), (0.16, 0.16, 0.08)],
                      rng), rng, 0.15), 0.9, 0.0, 0.35, rng.uniform(0.2, 0.6)))
    # the waterline: y_edge(x) wavy, land for y < y_edge
    xs = np.linspace(-length_m / 2, length_m / 2, 25)
    wave = rng.uniform(0.5, 4.0)
    edge = wave * np.sin(xs / rng.uniform(15, 40) + rng.uniform(0, 6)) + rng.normal(0, wave / 3, len(xs))
    edge = np.clip(edge, -1.5 * wave, 1.5 * wave)     # at most 6 m off the nominal waterline
    parts = []
    for k in range(len(xs) - 1):
        quad = np.array([(xs[k], edge[k]), (xs[k + 1], edge[k + 1]),
                         (xs[k + 1], -depth_m), (xs[k], -depth_m)])
        parts.append(_prism(quad, -3.0, height))
    objects_land = [(p, lawn) for p in parts]
    x0, y0 = _local_to_vessel(origin_v, along_deg, 0.0, 0.0)
    b.add(f"{tag}-land", "land", OBSTACLE, objects_land, x0, y0, along_deg)

    def place(x: float, y: float) -> tuple[float, float]:
        return _local_to_vessel(origin_v, along_deg, x, y)

    def edge_at(x: float) -> float:
        return float(np.interp(x, xs, edge))

    # rip-rap or sand along parts of the waterline
    if rng.random() < 0.6:
        rock = b.material(f"{tag}-riprap", Material(_grey((0.22, 0.2, 0.18), rng, 0.3), 0.95, 0.0, 0.6, 2.5))
        for k in range(len(xs) - 1):
            if rng.random() < 0.5:
                continue
            w = rng.uniform(1.5, 4.0)
            quad = np.array([(xs[k], edge[k] + w * 0.6), (xs[k + 1], edge[k + 1] + w * 0.6),
                             (xs[k + 1], edge[k + 1] - w), (xs[k], edge[k] - w)])
            slab = _prism(quad, -1.0, height + 0.3, top_xy=quad[2:])
            b.add(f"{tag}-riprap{k}", "riprap", OBSTACLE, [(slab, rock)], x0, y0, along_deg)
    # trees: trunks on land, crowns overhanging the water near the edge (and their shadows)
    bark = b.material(f"{tag}-bark", Material((0.08, 0.05, 0.03), 0.9))
    clumps = rng.uniform(-length_m / 2 + 10, length_m / 2 - 10, int(rng.integers(3, 9)))
    for _ in range(int(rng.integers(20, 70))):      # in clumps along the shore, as in the photos
        x = float(np.clip(rng.choice(clumps) + rng.normal(0, 10), -length_m / 2 + 5, length_m / 2 - 5))
        back = float(rng.exponential(12.0)) + 0.5
        _add_tree(b, tag, place(x, edge_at(x) - back), along_deg, float(rng.uniform(2.0, 7.0)),
                  height, bark)
    # a road behind the houses, houses with gabled roofs, cars on drives
    road_y = -rng.uniform(40.0, 80.0)
    asphalt = b.material(f"{tag}-asphalt", Material(_grey((0.06, 0.06, 0.065), rng, 0.3), 0.8, 0.0, 0.2, 1.0))
    xv, yv = place(0.0, road_y)
    b.add(f"{tag}-road", "road", OBSTACLE, [(_box(length_m, rng.uniform(6, 9), 0.08, 0, 0, height), asphalt)],
          xv, yv, along_deg)
    wall = b.material(f"{tag}-wall", Material(_jitter(_pick([(0.6, 0.55, 0.45), (0.7, 0.7, 0.68),
                                                             (0.35, 0.2, 0.12)], rng), rng), 0.7))
    clearings: list[tuple[float, float, float, float]] = []     # house centres, half sizes
    x = -length_m / 2 + rng.uniform(5, 25)
    while x < length_m / 2 - 15:
        lx, ly = rng.uniform(9, 18), rng.uniform(8, 14)
        y = road_y + ly / 2 + rng.uniform(8, 25)
        y = min(y, edge_at(x) - ly / 2 - rng.uniform(12, 30))
        roof = b.material(f"{tag}-roof{b.next_instance}", Material(_jitter(_pick(_ROOF_RGB, rng), rng), 0.8,
                                                                   0.0, 0.25, 1.5))
        wall_h = rng.uniform(3, 6)
        xv, yv = place(x, y)
        clearings.append((x, y, lx / 2 + WOOD_CLEARING_M, ly / 2 + WOOD_CLEARING_M))
        b.add(f"{tag}-house{b.next_instance}", "house", OBSTACLE,
              [(_box(lx, ly, wall_h, 0, 0, height), wall), (_gable(lx + 0.6, ly + 0.6, rng.uniform(2, 4),
                                                                height + wall_h), roof)],
              xv, yv, along_deg)
        if rng.random() < 0.6:
            car_mat = b.material(f"{tag}-car{b.next_instance}",
                                 Material(_jitter(_pick(_CAR_RGB, rng), rng, 0.1), 0.3, 0.5, 0.05))
            xv, yv = place(x + lx / 2 + 3.0, road_y + rng.uniform(6, 12))
            b.add(f"{tag}-car{b.next_instance}", "car", OBSTACLE,
                  [(_box(4.5, 1.8, 0.8, 0, 0, height + 0.2), car_mat),
                   (_box(2.4, 1.6, 0.6, -0.2, 0, height + 1.0), car_mat)], xv, yv, along_deg + 90.0)
        x += lx + rng.uniform(8, 30)
    if wooded_share > 0 and rng.random() < wooded_share:
        _add_woods(b, tag, place, edge_at, along_deg, length_m, height, bark, road_y, clearings)
    return edge_at


#: share of shores whose land is wooded behind the waterline, not a lawn with a few clumps:
#: most of the lake-shore photos show canopy over most of the land, houses in clearings
WOODED_SHARE = 0.65
#: metres of open ground kept round a house and either side of the road's centre in a wood
WOOD_CLEARING_M = 2.0
WOOD_ROAD_CLEARING_M = 5.0
#: woods reach this far either way along the shore from the point nearest the vessel: a
#: camera at 150 m, offset by 10 %, sees about 120 m either way
WOOD_HALF_LENGTH_M = 130.0
#: a crown's footprint is about 2.24 r^2 (mean of 200 crowns of :func:`_crown_lobes`, 10-90 %:
#: 1.96-2.52), not pi (1.15 r)^2: its lobes reach 1.15 r only here and there
CROWN_AREA_PER_R2 = 2.24


def _add_tree(b: _Builder, tag: str, at_v: tuple[float, float], along_deg: float, radius_m: float,
              ground_z: float, bark: str) -> None:
    """A tree at ``at_v`` (vessel frame): a trunk and a lumpy crown of radius ``radius_m``,
    1.5-3 radii tall, in one of the greens of sunlit deciduous canopy in the lake-shore
    photos (linear RGB) or a darker conifer's, leaf clusters a metre or less across."""
    rng = b.rng
    crown_rgb = _pick([(0.04, 0.1, 0.02), (0.07, 0.14, 0.03), (0.1, 0.16, 0.04), (0.05, 0.08, 0.03),
                       (0.12, 0.13, 0.05), (0.1, 0.22, 0.04), (0.14, 0.25, 0.06)], rng)
    crown = b.material(f"{tag}-crown{b.next_instance}", Material(_jitter(crown_rgb, rng), 0.95,
                                                                 0.0, 0.5, 2.5))
    tall = float(rng.uniform(1.5, 3.0)) * radius_m
    b.add(f"{tag}-tree{b.next_instance}", "tree", OBSTACLE,
          [(_cylinder(0.25 + 0.03 * radius_m, tall - radius_m, 0, 0, ground_z, 6), bark)]
          + [(lobe, crown) for lobe in _crown_lobes(radius_m, ground_z + tall - 0.5 * radius_m, rng)],
          at_v[0], at_v[1], along_deg)


def _add_woods(b: _Builder, tag: str, place, edge_at, along_deg: float, length_m: float,
               ground_z: float, bark: str, road_y: float,
               clearings: list[tuple[float, float, float, float]]) -> None:
    """Canopy over the land from 3 m behind the waterline to 35-75 m back, within
    :data:`WOOD_HALF_LENGTH_M` of the shore's middle (no camera of the family sees farther
    along it): trees of 3.5-8 m crown radius at uniform random places, their crowns' areas
    adding up to 0.6-1.4 times the band's (they overlap, so 45-75 % of it is covered, less
    the clearings), none with its trunk within a house's clearing or on the road, and none
    beyond the builder's ``view_reach_m`` (the view, not the scene, is what the woods fill).
    Local coordinates of the shore (x along it, y toward the water)."""
    rng = b.rng
    depth_m = float(rng.uniform(35.0, 75.0))
    cover = float(rng.uniform(0.6, 1.4))
    half_m = min(WOOD_HALF_LENGTH_M, length_m / 2 - 5)
    r_low, r_high = 3.5, 8.0
    # E[r^2] of r ~ U(r_low, r_high), times a crown's footprint per r^2
    mean_crown_m2 = CROWN_AREA_PER_R2 * (r_high ** 3 - r_low ** 3) / (3 * (r_high - r_low))
    for _ in range(int(cover * 2 * half_m * depth_m / mean_crown_m2)):
        x = float(rng.uniform(-half_m, half_m))
        y = edge_at(x) - float(rng.uniform(3.0, depth_m))
        radius = float(rng.uniform(r_low, r_high))
        at_v = place(x, y)
        if abs(y - road_y) < WOOD_ROAD_CLEARING_M or any(
                abs(x - cx) < hx and abs(y - cy) < hy for cx, cy, hx, hy in clearings):
            continue
        if b.view_reach_m is not None and math.hypot(*at_v) > b.view_reach_m + radius:
            continue        # never in view: its draws are made all the same
        _add_tree(b, tag, at_v, along_deg, radius, ground_z, bark)


#: dock and pontoon decking: weathered and stained wood
_WOOD_RGB = [(0.28, 0.2, 0.12), (0.35, 0.3, 0.24), (0.2, 0.14, 0.08), (0.45, 0.42, 0.38)]
#: white and grey composite boards, which many of the lake-shore photos' docks are
_COMPOSITE_RGB = [(0.72, 0.72, 0.7), (0.58, 0.58, 0.56)]
#: marina pontoon decking: two weathered woods beside white and grey composite boards. The
#: marina tiles' pontoons are pale (median linear 0.54, p10-p90 0.29-0.81: as bright as the
#: boats, 0.47), where an all-wood palette (0.08-0.45) had taught "pale and flat is a boat"
_PONTOON_RGB = [(0.35, 0.3, 0.24), (0.45, 0.42, 0.38), (0.72, 0.72, 0.7), (0.6, 0.6, 0.57)]
#: the other pontoons: poured or precast concrete, pale as the tiles' are
_PONTOON_CONCRETE_RGB = (0.62, 0.61, 0.58)
#: drive-on jet-ski ports: white, light grey, black and blue plastic floats
_PORT_RGB = [(0.8, 0.8, 0.78), (0.55, 0.56, 0.58), (0.06, 0.06, 0.07), (0.08, 0.16, 0.4)]
_PORT_P = np.array([0.5, 0.25, 0.15, 0.1])
#: a port's deck above the water, and the height of its two keel rails on it
PORT_DECK_Z_M = 0.18
PORT_RAIL_HEIGHT_M = 0.12


def _planks(b: _Builder, tag: str, palette: list):
    """A planked deck material in one of ``palette``'s colours (a lake-shore dock: wood in 4
    of 6 draws, white or grey composite boards in 2; a marina pontoon: :data:`_PONTOON_RGB`)."""
    rng = b.rng
    rgb = _pick(palette, rng)
    return b.material(f"{tag}-wood", Material(_jitter(rgb, rng, 0.2), 0.85, 0.0, 0.35, 3.0, pattern="planks"))


def add_jetski_port(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float, tag: str,
                    with_jetski: bool):
    """A drive-on jet-ski port (a floating plastic cradle, ``obstacle``) centred at
    ``(x_v, y_v)``, its long axis along ``rel_heading_deg``: a slab 3.3-3.8 m by 1.9-2.3 m,
    pointed at its +x end (toward the dock), with two keel rails on top; with a jet ski
    (``ship``) resting on the rails when ``with_jetski``. Returns the objects made."""
    rng = b.rng
    length, width = rng.uniform(3.3, 3.8), rng.uniform(1.9, 2.3)
    plastic = b.material(f"{tag}-port", Material(_jitter(_pick(_PORT_RGB, rng, _PORT_P), rng, 0.08),
                                                 0.45, 0.0, 0.05, 1.0))
    half_l, half_w = length / 2, width / 2
    outline = np.array([(-half_l, -half_w), (half_l - 0.6, -half_w), (half_l, -0.35),
                        (half_l, 0.35), (half_l - 0.6, half_w), (-half_l, half_w)])
    parts = [(_prism(outline, -0.12, PORT_DECK_Z_M), plastic)]
    parts += [(_box(length * 0.7, 0.25, PORT_RAIL_HEIGHT_M, -0.1 * length, side * (half_w - 0.3),
                    PORT_DECK_Z_M), plastic) for side in (-1, 1)]
    made = [b.add(f"{tag}-port", "port", OBSTACLE, parts, x_v, y_v, rel_heading_deg)]
    if with_jetski:
        jetski = add_leisure_boat(b, x_v, y_v, rel_heading_deg, length * 0.88, "jetski")
        # out of the water, its hull resting on the rails (above every part of the port)
        lift_m = PORT_DECK_Z_M + PORT_RAIL_HEIGHT_M - min(
            float(np.asarray(part.mesh.vertices)[:, 2].min()) for part in jetski.parts)
        for part in jetski.parts:
            part.mesh.apply_translation((0.0, 0.0, lift_m))
        made.append(jetski)
    return made


def add_private_dock(b: _Builder, start_v: tuple[float, float], out_deg: float, length_m: float,
                     tag: str) -> list:
    """A dock from the shore at ``start_v`` out along ``out_deg`` (from the bow, clockwise;
    wood or white and grey composite boards): a walkway, a T or L head, a boat lift beside it
    (a frame of posts and rails, a canopy on most) with a boat in it or not, and opposite it
    one or two drive-on jet-ski ports (most with a jet ski on) or a boat or jet ski tied
    alongside."""
    rng = b.rng
    wood = _planks(b, tag, _WOOD_RGB + _COMPOSITE_RGB)
    width = rng.uniform(1.2, 2.4)
    deck_z = rng.uniform(0.3, 0.9)
    parts = [(_box(length_m, width, 0.25, length_m / 2, 0.0, deck_z), wood)]
    head = str(rng.choice(["T", "L", "none"], p=[0.4, 0.35, 0.25]))
    if head != "none":
        head_len = rng.uniform(6, 14)
        y_off = 0.0 if head == "T" else rng.choice([-1, 1]) * (head_len / 2 - width / 2)
        parts.append((_box(width * 1.5, head_len, 0.25, length_m - width * 0.75, y_off, deck_z), wood))
    dock = b.add(f"{tag}-dock", "dock", OBSTACLE, parts, *start_v, out_deg)
    placed = [dock]
    side = float(rng.choice([-1, 1]))

    def beside(x_local: float, y_local: float) -> tuple[float, float]:
        return _local_to_vessel(start_v, out_deg, x_local, y_local)

    if rng.random() < 0.75 and length_m > 11:
        # a lift: four posts, two rails, usually a canopy; 3.2-3.8 m wide, 7-9 m long
        lift_w, lift_l = rng.uniform(3.2, 3.8), rng.uniform(7.0, 9.0)
        x_c = rng.uniform(lift_l / 2 + 1, length_m - lift_l / 2)
        y_c = side * (width / 2 + 0.4 + lift_w / 2)
        steel = b.material(f"{tag}-lift", Material(_grey((0.5, 0.5, 0.52), rng, 0.2), 0.4, 0.7, 0.05))
        posts = [(_cylinder(0.12, 4.2, sx * lift_l / 2, sy * lift_w / 2, -1.0, 6), steel)
                 for sx in (-1, 1) for sy in (-1, 1)]
        rails = [(_box(lift_l, 0.2, 0.2, 0, sy * lift_w / 2, 2.9), steel) for sy in (-1, 1)]
        lift_parts = posts + rails
        if rng.random() < 0.75:
            canopy_rgb = _pick(_COVER_RGB + [(0.75, 0.75, 0.72)] * 2, rng)
            canopy = b.material(f"{tag}-canopy", Material(_jitter(canopy_rgb, rng), 0.85, 0.0, 0.15, 1.5))
            lift_parts.append((_gable(lift_l + 0.6, lift_w + 0.5, rng.uniform(0.5, 1.0), 3.2), canopy))
        xv, yv = beside(x_c, y_c)
        placed.append(b.add(f"{tag}-lift", "lift", OBSTACLE, lift_parts, xv, yv, out_deg))
        if rng.random() < 0.6:
            placed.append(add_leisure_boat(b, xv, yv, out_deg + float(rng.choice([0.0, 180.0])),
                                           lift_l * rng.uniform(0.7, 0.85)))
    if rng.random() < 0.3 and length_m > 8:
        # one or two drive-on jet-ski ports along the dock, across it, opposite the lift
        n_ports = int(rng.integers(1, 3))
        x_c = rng.uniform(3.0, max(3.1, length_m - 2.6 * n_ports))
        y_c = -side * (width / 2 + 0.25 + 1.8)
        for k in range(n_ports):
            xv, yv = beside(x_c + 2.6 * k, y_c)
            made = add_jetski_port(b, xv, yv, out_deg - side * 90.0, f"{tag}-{k}",
                                   with_jetski=bool(rng.random() < 0.65))
            if _overlaps_others(made, b, margin_m=0.1):
                del b.objects[-len(made):]
            else:
                placed += made
    elif rng.random() < 0.6 and length_m > 6:
        boat_l = rng.uniform(4.0, 8.0)
        kind = "jetski" if rng.random() < 0.25 else None
        x_c = rng.uniform(boat_l / 2, max(boat_l / 2 + 0.1, length_m - boat_l / 2))
        y_c = -side * (width / 2 + 0.5 + boat_l * 0.2)
        xv, yv = beside(x_c, y_c)
        boat = add_leisure_boat(b, xv, yv, out_deg + float(rng.choice([0.0, 180.0])), boat_l, kind)
        if _overlaps_others([boat], b, margin_m=0.2):
            b.objects.remove(boat)
        else:
            placed.append(boat)
    return placed


def build_lakeshore(b: _Builder, hull: Polygon, hull_xy: np.ndarray, side: int, gap_m: float) -> None:
    """The vessel of interest off a residential shore on ``side`` (+1 starboard): docks reach
    toward it; one that would come nearer than ``gap_m`` to its hull is shortened."""
    rng = b.rng
    skew = float(rng.uniform(-15, 15))
    reach = float(rng.uniform(8, 25))             # how far the docks reach out from the shore
    half_beam = float(hull_xy[:, 1].max() if side > 0 else -hull_xy[:, 1].min())
    shore_y = side * (half_beam + gap_m + reach)
    along = skew if side > 0 else 180.0 + skew    # water on the left of the shore's direction
    edge_at = add_shore(b, (0.0, shore_y), along, "shore", wooded_share=WOODED_SHARE)
    limit = gap_m + 0.05
    vessel_fp = b.objects[0].footprint()          # W, as every footprint
    out_deg = along - 90.0                        # from the shore toward the water
    x = float(rng.uniform(-120, -90))
    while x < 120:
        start = _local_to_vessel((0.0, shore_y), along, x, edge_at(x) - 1.5)
        length = reach * rng.uniform(0.5, 1.0) + 1.5 if abs(x) > 30 else reach + 1.5 + rng.uniform(0, 6)
        for _ in range(3):                        # shorten the dock until it keeps the gap
            if length <= 4.0:
                break
            n_before = len(b.objects)
            add_private_dock(b, start, out_deg, length, f"dock{b.next_instance}")
            new = b.objects[n_before:]
            nearest = min(o.footprint().distance(vessel_fp) for o in new)
            if nearest >= limit and not _overlaps_others(new, b):
                break
            del b.objects[n_before:]
            if nearest >= limit:                  # it hit another dock: leave the place empty
                break
            length -= limit - nearest + 0.5
        x += float(rng.uniform(18, 45))


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


# ------------------------------------------------------------------------ the marina


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
# fish crates (blue, red, white, grey) and nets (green, orange, blue)
_CRATE_RGB = [(0.02, 0.1, 0.4), (0.5, 0.03, 0.02), (0.75, 0.75, 0.72), (0.3, 0.3, 0.3)]
_NET_RGB = [(0.03, 0.15, 0.05), (0.6, 0.2, 0.01), (0.03, 0.08, 0.3)]


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


def keep_gap(b: _Builder, gap_m: float) -> None:
    """Drop what a family placed nearer to the vessel than ``gap_m`` (a tree crown over the
    water, a rip-rap stone): the scene's gap is its nearest obstacle."""
    vessel_fp = b.objects[0].footprint()
    b.objects[1:] = [o for o in b.objects[1:] if o.footprint().distance(vessel_fp) >= gap_m]


# ------------------------------------------------------------------------ the look


def sample_realistic_environment(rng: np.random.Generator, family: str) -> Environment:
    """The classic draw (sun, sky, waves, haze) with real harbours' water and a consumer
    drone's camera: water from clear blue to brown (turbid tan or olive on 70 % of lake
    shores), calmer and with fewer whitecaps; vignetting, white balance off by a few percent,
    JPEG at quality 60-95, motion blur in a third of frames."""
    env = sample_environment(rng)
    return replace(
        env,
        water_rgb=_jitter(_pick(_TURBID_WATER_RGB if family == "lakeshore" and rng.random() < 0.7
                                else _REAL_WATER_RGB, rng), rng, 0.3),
        wave_scale=float(rng.uniform(0.02, 0.35)),
        foam_coverage=float(rng.uniform(0.0, 0.15)),       # sheltered water: few whitecaps
        vignetting=float(rng.uniform(0.0, 0.35)),
        white_balance=tuple(float(v) for v in rng.uniform(0.9, 1.1, 3)),
        jpeg_quality=int(rng.integers(60, 96)),
        motion_blur_px=float(rng.uniform(0.5, 2.5)) if rng.random() < 0.33 else 0.0,
        motion_blur_deg=float(rng.uniform(0.0, 180.0)),
    )
