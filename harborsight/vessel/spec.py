"""``vessel.yaml``: the vessel of interest's hull (mesh or AIS dimensions) and sections."""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from harborsight.errors import InputError, brief
from harborsight.text_formats import load_yaml_text
from harborsight.vessel.layers import above_water_layers, largest
from harborsight.vessel.outline import (
    BOW_SHAPES,
    bow_looks_aft,
    mesh_in_vessel_frame,
    outline_from_dimensions,
    outline_from_mesh,
)
from harborsight.vessel.sections import MAX_SECTIONS, SectionedOutline

DEFAULT_SECTIONS = 16
#: one sigma (m) of where a hull drawn from AIS dimensions lies against the real hull: the
#: four dimensions are whole metres and the bow a guessed taper. On the seed-7 bench's six
#: procedural hulls, drawn from their own rounded extents, it took 0.6 m for the truth to lie
#: within two sigma of the readings 90.9 % of the time and under the lower bound 3.2 %
#: (73.6 % and 8.9 % without it; docs/results.md). ``vessel from-ais`` writes it.
AIS_OUTLINE_SIGMA_M = 0.6
#: the largest outline sigma taken: beyond it the hull is not known at all
MAX_OUTLINE_SIGMA_M = 50.0


@dataclass(frozen=True)
class VesselSpec:
    """A vessel in its own frame V (x bow, y starboard, z down, origin at the antenna).

    ``outline`` is the convex outline used for sections (clockwise from above, from the bow);
    ``hull_points`` are V-frame points whose convex hull contains the vessel above the
    waterline, used to find the vessel's own pixels in an image (the water hides the rest).
    """

    name: str
    outline: np.ndarray
    hull_points: np.ndarray
    n_sections: int | None = DEFAULT_SECTIONS
    section_length_m: float | None = None
    source: str | None = None
    #: the whole vessel as a mesh in V (metres), when the spec gives one
    mesh: trimesh.Trimesh | None = field(default=None, repr=False, compare=False)
    #: what a user should check in the spec (said once by the commands that load it)
    notes: tuple[str, ...] = field(default=(), compare=False)
    #: one sigma (m) of the outline's place against the real hull (``outline_sigma_m``; 0: a
    #: mesh taken as exact), a systematic term of every distance's sigma
    outline_sigma_m: float = 0.0
    #: V-frame point sets, one per layer of the vessel above the waterline (a hull, a
    #: deckhouse, a mast; at most 48), whose convex hulls together contain it
    #: (:func:`harborsight.vessel.layers.above_water_layers`); empty: the convex hull
    #: of ``hull_points`` alone (a prism from dimensions, which is exact)
    silhouette_layers: tuple[np.ndarray, ...] = field(default=(), repr=False, compare=False)
    _sections: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def own_layers(self) -> tuple[np.ndarray, ...]:
        """The point sets whose projected convex hulls make the vessel's image region."""
        return self.silhouette_layers or (self.hull_points,)

    @functools.cached_property
    def alignment_layers(self) -> tuple[np.ndarray, ...]:
        """The layers the pose alignment fits (:func:`harborsight.vessel.layers.largest`):
        the hull, a deckhouse, a mast; not a railing's posts, which a mask does not show
        and which would cost the alignment an outline each."""
        return largest(self.own_layers)

    @property
    def length_m(self) -> float:
        return float(np.ptp(self.outline[:, 0]))

    @property
    def beam_m(self) -> float:
        return float(np.ptp(self.outline[:, 1]))

    def sections(
        self, n_sections: int | None = None, section_length_m: float | None = None
    ) -> SectionedOutline:
        """Split the outline (cached); arguments override the spec's own setting."""
        if n_sections is None and section_length_m is None:
            n_sections, section_length_m = self.n_sections, self.section_length_m
        key = (n_sections, section_length_m)
        if key not in self._sections:
            self._sections[key] = SectionedOutline.split(self.outline, n_sections, section_length_m)
        return self._sections[key]


#: the largest vessel dimension taken (length, beam, air draft, a dimension, the hull's
#: distance from its antenna): the longest ships afloat are under 460 m, and a hull of
#: 1e30 m, or one whose length overflows to infinity, is a typo or a mesh in millimetres
MAX_VESSEL_SIZE_M = 1000.0
#: the smallest length or beam taken (the outline of a smaller box vanishes in rounding)
MIN_VESSEL_SIZE_M = 0.1
#: the largest mesh coordinate taken for gps_antenna and waterline_m (mesh units, which may
#: be millimetres: the hull itself is checked in metres once it is in the vessel frame)
MAX_MESH_COORDINATE = 1e6
#: YAML 1.2 float syntax; PyYAML (YAML 1.1) reads ``1e30`` or ``1.0e30`` as text
_NUMBER_TEXT = re.compile(r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?")


def _finite(value: Any, path: Path, key: str, what: str = "number of metres",
            part: str = "", limit: float | None = None) -> float:
    """``value`` as a finite float, else :class:`InputError` naming ``key`` (NaN, infinity,
    a whole number of 400 digits, a string, a list); ``part`` says which element it is.
    Text that is a number in YAML 1.2 (``1e3``, which PyYAML leaves as text) is read as
    one. ``limit``: the largest magnitude taken."""
    number = math.nan
    if isinstance(value, str) and len(value) < 400 and _NUMBER_TEXT.fullmatch(value.strip()):
        number = float(value)
    elif not isinstance(value, bool) and isinstance(value, (int, float)):
        try:
            number = float(value)
        except OverflowError:           # a whole number of 400 digits
            number = math.inf
    if not math.isfinite(number):
        raise InputError(path, key, f"{part}expected a finite {what}, got {brief(value)}")
    if limit is not None and abs(number) > limit:
        raise InputError(path, key, f"{part}{number:g} is beyond {limit:g}: larger than any "
                         "vessel (a typo, or a value in millimetres?)")
    return number


def _positive(doc: dict, key: str, path: Path, prefix: str = "",
              limit: float | None = MAX_VESSEL_SIZE_M) -> float:
    value = _finite(doc.get(key), path, f"{prefix}{key}", limit=limit)
    if value < 0:
        raise InputError(path, f"{prefix}{key}", f"must not be negative, got {value}")
    return value


def _check_mesh_size(mesh_v: trimesh.Trimesh, spec_path: Path, mesh_name: str) -> None:
    """Refuse a hull in the vessel frame that is larger than any vessel (a mesh in
    millimetres) or lies far from its antenna (gps_antenna or waterline_m off)."""
    vertices = np.asarray(mesh_v.vertices)
    extent = np.ptp(vertices, axis=0)
    if extent.max() > MAX_VESSEL_SIZE_M:
        raise InputError(spec_path, "hull_mesh", f"{mesh_name} spans {extent.max():.4g} units: "
                         f"more than {MAX_VESSEL_SIZE_M:g} m, not a vessel in metres (a mesh in "
                         "millimetres?)")
    reach = np.abs(vertices).max(axis=0)
    if reach[:2].max() > MAX_VESSEL_SIZE_M:
        raise InputError(spec_path, "gps_antenna", f"the hull lies up to {reach[:2].max():.4g} m "
                         f"from the antenna: more than {MAX_VESSEL_SIZE_M:g} m (check its "
                         "coordinates and mesh_axes)")
    if reach[2] > MAX_VESSEL_SIZE_M:
        raise InputError(spec_path, "waterline_m", f"the hull lies up to {reach[2]:.4g} m above "
                         f"or below the waterline: more than {MAX_VESSEL_SIZE_M:g} m")


def _load_mesh(mesh_path: Path, spec_path: Path) -> trimesh.Trimesh:
    try:
        found = mesh_path.is_file()
    except OSError as exc:            # a name too long for the file system, and the like
        raise InputError(spec_path, "hull_mesh", f"cannot look for {brief(mesh_path.name)}: "
                         f"{exc.strerror or exc}") from None
    if not found:
        raise InputError(spec_path, "hull_mesh", f"file not found: {mesh_path}")
    try:
        # unprocessed first: processing drops the faces of NaN vertices without a word, and a
        # hull with faces missing gives clearances too small (issue #30: 0.71 m read 0.22 m)
        mesh = trimesh.load(mesh_path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputError(spec_path, "hull_mesh", f"cannot load {mesh_path.name}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(spec_path, "hull_mesh", f"{mesh_path.name} holds no triangles")
    vertices = np.asarray(mesh.vertices, dtype=float)
    bad = int((~np.isfinite(vertices).all(axis=1)).sum())
    if bad:
        raise InputError(spec_path, "hull_mesh", f"{mesh_path.name}: {bad} of {len(vertices)} "
                         "vertices are not finite (NaN or infinity)")
    extent = np.ptp(vertices[np.unique(mesh.faces)], axis=0)
    if (extent > 1e-6).sum() < 2:
        raise InputError(spec_path, "hull_mesh", f"{mesh_path.name} is degenerate: its triangles "
                         f"span {extent.round(6).tolist()} m (a line or a point, not a hull)")
    mesh.merge_vertices()
    return mesh


def parse_vessel_spec(doc: Any, path: Path) -> VesselSpec:
    """Validate a parsed ``vessel.yaml`` (``path`` resolves ``hull_mesh`` and names errors)."""
    if not isinstance(doc, dict):
        raise InputError(path, None, "expected a YAML mapping")
    name = str(doc.get("name") or path.parent.name or "vessel")
    mode = doc.get("outline", "waterline")
    if mode not in ("waterline", "silhouette"):
        mode = _finite(mode, path, "outline", "height in metres (or waterline, silhouette)",
                       limit=MAX_VESSEL_SIZE_M)

    mesh_v = None
    notes: list[str] = []
    if doc.get("hull_mesh"):
        if not isinstance(doc["hull_mesh"], str):
            raise InputError(path, "hull_mesh", f"expected a mesh file name, got "
                             f"{brief(doc['hull_mesh'])}")
        mesh = _load_mesh(path.parent / doc["hull_mesh"], path)
        axes = doc.get("mesh_axes", ["bow", "port", "up"])
        antenna = doc.get("gps_antenna", [0.0, 0.0, 0.0])
        if not (isinstance(antenna, list) and len(antenna) == 3):
            raise InputError(path, "gps_antenna", f"expected [x, y, z] in metres, got {brief(antenna)}")
        antenna = [_finite(v, path, "gps_antenna", part=f"{axis}: ", limit=MAX_MESH_COORDINATE)
                   for axis, v in zip("xyz", antenna, strict=True)]
        waterline = _finite(doc.get("waterline_m", 0.0), path, "waterline_m",
                            limit=MAX_MESH_COORDINATE)
        if not isinstance(axes, list):
            raise InputError(path, "mesh_axes", f"expected three axis names, got {brief(axes)}")
        try:
            mesh_v = mesh_in_vessel_frame(mesh, axes, np.asarray(antenna, float), waterline)
        except (TypeError, ValueError) as exc:
            raise InputError(path, "mesh_axes", brief(str(exc), 120).strip("'\"")) from None
        _check_mesh_size(mesh_v, path, str(doc["hull_mesh"]))
        try:
            outline = outline_from_mesh(mesh_v, mode)
            hull_points = above_water_hull_points(mesh_v)
            layers = above_water_layers(mesh_v)
        except ValueError as exc:
            raise InputError(path, "outline", str(exc)) from exc
        aft = bow_looks_aft(outline)
        if aft is not None:
            notes.append(f"mesh_axes: {aft}")
    elif doc.get("dimensions"):
        layers = ()
        dims = doc["dimensions"]
        if not isinstance(dims, dict):
            raise InputError(path, "dimensions", "expected {to_bow, to_stern, to_port, to_starboard}")
        values = {k: _positive(dims, k, path, "dimensions.")
                  for k in ("to_bow", "to_stern", "to_port", "to_starboard")}
        for what, total in (("length (to_bow + to_stern)", values["to_bow"] + values["to_stern"]),
                            ("beam (to_port + to_starboard)",
                             values["to_port"] + values["to_starboard"])):
            if not MIN_VESSEL_SIZE_M <= total <= MAX_VESSEL_SIZE_M:
                raise InputError(path, "dimensions", f"{what} is {total:g} m: expected "
                                 f"{MIN_VESSEL_SIZE_M:g} to {MAX_VESSEL_SIZE_M:g} m")
        bow = dims.get("bow", "pointed")
        if bow not in BOW_SHAPES:
            raise InputError(path, "dimensions.bow", f"expected one of {', '.join(BOW_SHAPES)}, "
                             f"got {brief(bow)}")
        outline = outline_from_dimensions(**values, bow=bow)
        air_draft = _positive(doc, "air_draft_m", path) if "air_draft_m" in doc else 0.0
        hull_points = np.vstack((
            np.column_stack((outline, np.zeros(len(outline)))),
            np.column_stack((outline, np.full(len(outline), -air_draft))),
        ))
    else:
        raise InputError(path, "hull_mesh", "missing: give hull_mesh or dimensions")
    outline_sigma = 0.0
    if "outline_sigma_m" in doc:
        outline_sigma = _positive(doc, "outline_sigma_m", path, limit=MAX_OUTLINE_SIGMA_M)
    elif mesh_v is None:
        notes.append(f"outline_sigma_m: not given, so the hull drawn from its dimensions is taken "
                     f"as exact in every distance's sigma (AIS dimensions are whole metres and the "
                     f"bow's taper is guessed; `vessel from-ais` writes {AIS_OUTLINE_SIGMA_M:g} m)")

    n_sections: int | None = DEFAULT_SECTIONS
    section_length: float | None = None
    if "section_length_m" in doc:
        section_length = _positive(doc, "section_length_m", path, limit=10_000.0)
        if section_length == 0:
            raise InputError(path, "section_length_m", "must be positive")
        if section_length < 1e-6:       # the count would overflow: say what it means
            raise InputError(path, "section_length_m", f"{section_length:g} m asks for more "
                             f"than {MAX_SECTIONS} sections on any hull (give metres)")
        n_sections = None
    elif "sections" in doc:
        n = doc["sections"]
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise InputError(path, "sections", f"expected a positive whole number, got {brief(n)}")
        n_sections = n
    spec = VesselSpec(name, outline, hull_points, n_sections, section_length, str(path), mesh_v,
                      tuple(notes), outline_sigma, layers)
    try:
        spec.sections()
    except (ValueError, OverflowError) as exc:
        raise InputError(path, "section_length_m" if section_length else "sections", str(exc)) from None
    return spec


def above_water_hull_points(mesh_v) -> np.ndarray:
    """Vertices of the convex hull of the part of a V-frame mesh at or above the waterline
    (z <= 0, z down). The submerged hull is hidden by the water, and left in it would make
    the vessel's image region too large: seen obliquely, a point at depth d and horizontal
    distance r from the camera's nadir shows d·r/(H + d) nearer the nadir, so the bilge on
    the side facing the camera projects beyond the visible waterline (1-2 m at 60 m up,
    40 m off), and an obstacle there would be erased."""
    import trimesh

    above = mesh_v.slice_plane(plane_origin=[0.0, 0.0, 0.0], plane_normal=[0.0, 0.0, -1.0])
    if above is None or len(above.vertices) < 4:
        raise ValueError("no part of the hull mesh is above the waterline")
    return np.asarray(trimesh.convex.convex_hull(above.vertices).vertices)


def load_vessel_spec(path: str | Path) -> VesselSpec:
    """Read and validate a ``vessel.yaml``."""
    path = Path(path)
    try:
        is_dir, is_file = path.is_dir(), path.is_file()
    except (OSError, ValueError) as exc:    # a name too long to look up, a NUL byte
        raise InputError(Path(brief(str(path))), None, "cannot look this file name up: "
                         f"{getattr(exc, 'strerror', None) or exc}") from None
    if is_dir:
        raise InputError(path, None, "is a folder, not a file (expected a vessel.yaml)")
    if not is_file:
        raise InputError(path, None, "vessel spec not found")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(path, f"line {line}", f"not UTF-8 text (byte 0x{data[exc.start]:02x}): "
                         "save the file as UTF-8") from None
    return parse_vessel_spec(load_yaml_text(text, path), path)
