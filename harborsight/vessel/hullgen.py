"""Procedural hull meshes: a flared, pointed-bow hull with a deckhouse.

Used for the example vessel and by the simulator when no mesh is given. The mesh is in
naval CAD axes: +x bow, +y port, +z up, origin on the centreline at the transom and the
waterline (``mesh_axes: [bow, port, up]``, ``waterline_m: 0``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass(frozen=True)
class HullParameters:
    length_m: float = 32.0
    beam_m: float = 11.0
    draft_m: float = 4.0
    freeboard_m: float = 2.5
    bow_fraction: float = 0.3       # share of the length over which the hull narrows to the bow
    flare: float = 0.12             # deck half-beam exceeds the keel's by this share of the beam
    deckhouse: tuple[float, float, float, float] = (0.45, 0.75, 0.6, 6.0)
    # deckhouse: (start, end) as shares of the length, width as share of the beam, height m


def _half_beam(x: np.ndarray, p: HullParameters) -> np.ndarray:
    """Half-beam at the waterline along the hull: parallel midbody, curved pointed bow."""
    bow_start = (1.0 - p.bow_fraction) * p.length_m
    s = np.clip((x - bow_start) / (p.length_m - bow_start), 0.0, 1.0)
    return 0.5 * p.beam_m * np.sqrt(np.clip(1.0 - s**2, 0.0, 1.0)) * (0.92 + 0.08 * (1 - s))


def generate_hull_mesh(p: HullParameters = HullParameters()) -> trimesh.Trimesh:
    """Convex flared hull plus a box deckhouse, in metres (see module docstring)."""
    xs = np.linspace(0.0, p.length_m, 41)
    zs = np.array([-p.draft_m, -0.5 * p.draft_m, 0.0, p.freeboard_m])
    points = []
    for z in zs:
        # width grows with height: keel narrower, deck wider (flare)
        scale = 1.0 + p.flare * (z / (p.draft_m + p.freeboard_m))
        keel = 0.55 if z <= -p.draft_m else 1.0
        for x in xs:
            half = _half_beam(np.array([x]), p)[0] * scale * keel
            bow_x = x + (0.04 * p.length_m if z >= p.freeboard_m else 0.0) * (x >= xs[-1])
            points.append((bow_x, half, z))
            points.append((bow_x, -half, z))
    hull = trimesh.convex.convex_hull(np.array(points))
    start, end, width, height = p.deckhouse
    house = trimesh.creation.box(
        extents=((end - start) * p.length_m, width * p.beam_m, height)
    )
    house.apply_translation((0.5 * (start + end) * p.length_m, 0.0, p.freeboard_m + height / 2))
    return trimesh.util.concatenate([hull, house])
