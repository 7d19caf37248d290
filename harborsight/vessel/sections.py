"""A convex hull outline split into sections, and the outward band of each section.

The outline is a convex polygon walked clockwise *seen from above*, starting at the bow.
In the vessel frame (x bow, y starboard, z down) that is counter-clockwise in the x-y
plane's own orientation; in image coordinates it may be either, so orientation is
detected from the signed area.

**Bands.** The paper keeps, for each section, the obstacle points inside the section's
outward perpendicular band. Perpendicular strips alone leave wedge-shaped gaps outside
every convex corner (an obstacle dead ahead of a pointed bow would be missed), so we use
their natural completion: a point outside the hull belongs to the section that holds its
nearest hull point. Along a straight piece this *is* the perpendicular band; at a corner
inside a section the wedge goes to that section; at a corner where two sections meet the
wedge is split along the bisector of the two edge normals.

For a point ``p`` outside a convex polygon with edge lines ``n_j · x = c_j`` (``n_j``
outward unit normals), the edge with the largest signed line distance
``h_j = n_j · p - c_j`` carries the nearest point, and inside a corner wedge this rule
picks the edge whose normal is angularly closest, i.e. the bisector split. So:

    j* = argmax_j h_j,   s = clip((p - a_j*) · t_j*, 0, L_j*),   nearest = a_j* + s t_j*

and the section is found from the arc-length position of ``nearest`` along the outline.
Cost: ``O(P · E)`` for P points and E polygon edges, all vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: more sections than this is a mistake (a section length in the wrong unit), not a request:
#: 0.000001 m on a 40 m hull asked for 80 million and ran out of memory (issue #30)
MAX_SECTIONS = 1000


def _signed_area(vertices: np.ndarray) -> float:
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


@dataclass(frozen=True)
class SectionAssignment:
    """Per point: section index (-1 when inside the hull), distance and nearest hull point."""

    section: np.ndarray
    distance: np.ndarray
    nearest: np.ndarray


class SectionedOutline:
    """Convex polygon ``vertices (K, 2)`` with section breaks on its perimeter.

    ``break_edge[k]`` is the edge (from vertex e to e+1) that break point k lies on; break 0
    is vertex 0 (the bow). Section k runs from break k to break k+1 along the outline.
    """

    def __init__(self, vertices: np.ndarray, break_points: np.ndarray, break_edge: np.ndarray):
        self.vertices = np.asarray(vertices, float)
        self.break_points = np.asarray(break_points, float)
        self.break_edge = np.asarray(break_edge, int)
        if len(self.vertices) < 3:
            raise ValueError(f"an outline needs at least 3 vertices, got {self.vertices.shape}")
        start = self.vertices
        end = np.roll(self.vertices, -1, axis=0)
        vec = end - start
        self.edge_start = start
        self.edge_length = np.hypot(vec[:, 0], vec[:, 1])
        if np.any(self.edge_length <= 0):
            raise ValueError("outline has repeated vertices")
        self.edge_dir = vec / self.edge_length[:, None]
        sign = 1.0 if _signed_area(self.vertices) > 0 else -1.0
        # outward normal: right of the direction for a positively oriented polygon
        self.edge_normal = sign * np.column_stack((self.edge_dir[:, 1], -self.edge_dir[:, 0]))
        self.edge_offset = np.concatenate(([0.0], np.cumsum(self.edge_length)[:-1]))
        self.perimeter = float(self.edge_length.sum())
        self._build_lines()
        along = np.einsum(
            "ij,ij->i", self.break_points - self.edge_start[self.break_edge],
            self.edge_dir[self.break_edge],
        )
        self.break_position = self.edge_offset[self.break_edge] + np.clip(
            along, 0.0, self.edge_length[self.break_edge]
        )
        self.break_position[0] = 0.0
        # band boundary at each break: a ray along the edge normal, or along the bisector of
        # the two normals when the break sits on a corner (within 1e-12 m, as
        # section_polyline decides it; a break a hair past a corner is on its edge)
        n_edges = len(self.edge_start)
        into = self.break_position - self.edge_offset[self.break_edge]
        at_start = into <= 1e-12
        at_end = self.edge_length[self.break_edge] - into <= 1e-12
        #: whether each break sits on a corner of the outline (else inside an edge)
        self.break_on_corner = at_start | at_end
        before = np.where(at_start, (self.break_edge - 1) % n_edges, self.break_edge)
        after = np.where(at_end & ~at_start, (self.break_edge + 1) % n_edges, self.break_edge)
        ray = self.edge_normal[before] + self.edge_normal[after]
        self.break_ray = ray / np.linalg.norm(ray, axis=1, keepdims=True)

    def _edge_at(self, position: np.ndarray) -> np.ndarray:
        position = np.mod(position, self.perimeter)
        return np.clip(np.searchsorted(self.edge_offset, position, side="right") - 1,
                       0, len(self.vertices) - 1)

    def _build_lines(self) -> None:
        """Group runs of collinear edges into lines (a vertex may sit mid-line, e.g. the bow)."""
        prev_normal = np.roll(self.edge_normal, 1, axis=0)
        first_of_run = np.einsum("ij,ij->i", self.edge_normal, prev_normal) <= 1.0 - 1e-12
        if not first_of_run.any():
            raise ValueError("outline is degenerate (all edges collinear)")
        starts = np.flatnonzero(first_of_run)
        # rotate so the first run starts at index 0, then sum edge lengths per run
        rolled = np.roll(self.edge_length, -starts[0])
        run_len = np.add.reduceat(rolled, starts - starts[0])
        self.line_start = self.edge_start[starts]
        self.line_dir = self.edge_dir[starts]
        self.line_normal = self.edge_normal[starts]
        self.line_length = run_len
        self.line_offset = self.edge_offset[starts]
        self._line_c = np.einsum("ij,ij->i", self.line_normal, self.line_start)
        self._line_normal_t = np.ascontiguousarray(self.line_normal.T)

    @classmethod
    def split(
        cls, vertices: np.ndarray, n_sections: int | None = None,
        section_length: float | None = None,
    ) -> SectionedOutline:
        """Split a polygon (starting at the bow) into equal-length sections.

        Give ``n_sections`` or ``section_length`` (then ``n = max(1, round(P / length))``).
        """
        vertices = np.asarray(vertices, float)
        lengths = np.hypot(*(np.roll(vertices, -1, axis=0) - vertices).T)
        perimeter = float(lengths.sum())
        if n_sections is None:
            if not section_length or section_length <= 0:
                raise ValueError("give n_sections or a positive section_length")
            n_sections = max(1, round(perimeter / section_length))
        if n_sections < 1:
            raise ValueError(f"n_sections must be at least 1, got {n_sections}")
        if n_sections > MAX_SECTIONS:
            raise ValueError(f"{n_sections} sections of {perimeter / n_sections:.3g} m on a "
                             f"{perimeter:.1f} m outline: more than {MAX_SECTIONS}")
        offsets = np.concatenate(([0.0], np.cumsum(lengths)))
        positions = np.arange(n_sections) * perimeter / n_sections
        edges = np.clip(np.searchsorted(offsets, positions, side="right") - 1, 0, len(vertices) - 1)
        frac = (positions - offsets[edges]) / lengths[edges]
        nxt = np.roll(vertices, -1, axis=0)
        points = vertices[edges] + frac[:, None] * (nxt[edges] - vertices[edges])
        return cls(vertices, points, edges)

    @property
    def n_sections(self) -> int:
        return len(self.break_points)

    def transformed(self, point_map) -> SectionedOutline:
        """The outline mapped point-wise (e.g. projected into the image).

        Valid for maps that keep straight lines straight and the polygon convex, such as
        a perspective projection of a planar polygon in front of the camera.
        """
        return SectionedOutline(point_map(self.vertices), point_map(self.break_points),
                                self.break_edge)

    def section_polyline(self, k: int) -> np.ndarray:
        """Points of section k from its start break to its end break, corners included."""
        n = self.n_sections
        pos_a = self.break_position[k]
        pos_b = self.break_position[k + 1] if k + 1 < n else self.perimeter
        inside = (self.edge_offset > pos_a + 1e-12) & (self.edge_offset < pos_b - 1e-12)
        end_point = self.break_points[(k + 1) % n]
        return np.vstack((self.break_points[k], self.vertices[inside], end_point))

    def section_endpoints(self) -> np.ndarray:
        """``(n, 2, 2)``: start and end break point of each section."""
        return np.stack((self.break_points, np.roll(self.break_points, -1, axis=0)), axis=1)

    def points_at(self, position: np.ndarray) -> np.ndarray:
        """Outline points at arc-length positions (0 at the bow, wrapping around)."""
        position = np.mod(np.asarray(position, float), self.perimeter)
        edge = self._edge_at(position)
        along = position - self.edge_offset[edge]
        return self.edge_start[edge] + along[:, None] * self.edge_dir[edge]

    def samples(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """``count`` points evenly spaced along the outline and their sections (cached)."""
        cache = self.__dict__.setdefault("_samples", {})
        if count not in cache:
            positions = (np.arange(count) + 0.5) * self.perimeter / count
            cache[count] = (self.points_at(positions), self.section_of_position(positions))
        return cache[count]

    def section_of_position(self, position: np.ndarray) -> np.ndarray:
        """Section index of arc-length positions along the outline (0 at the bow)."""
        position = np.mod(position, self.perimeter)
        return np.searchsorted(self.break_position, position, side="right") - 1

    def assign(self, points: np.ndarray) -> SectionAssignment:
        """Nearest hull point and section of each point ``(P, 2)`` (see module docstring).

        Points inside the polygon (or on it) get section -1 and distance 0.
        """
        points = np.asarray(points, float).reshape(-1, 2)
        if len(points) == 0:
            return SectionAssignment(np.zeros(0, int), np.zeros(0), np.zeros((0, 2)))
        h = np.dot(points, self._line_normal_t)     # (P, L) signed line distances
        h -= self._line_c
        j = np.argmax(h, axis=1)
        outside = h[np.arange(len(points)), j] > 0
        start, direction = self.line_start[j], self.line_dir[j]
        rel = points - start
        along = np.einsum("ij,ij->i", rel, direction)
        length = self.line_length[j]
        clamped = np.clip(along, 0.0, length)
        direction *= clamped[:, None]
        nearest = start + direction
        distance = np.hypot(*(points - nearest).T)
        # a corner that is also a break: the line's own side decides (bisector split)
        eps = 1e-9 * length
        position = self.line_offset[j] + np.clip(along, eps, length - eps)
        section = self.section_of_position(position)
        section = np.where(outside, section, -1)
        distance = np.where(outside, distance, 0.0)
        return SectionAssignment(section, distance, nearest)
