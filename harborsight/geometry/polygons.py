"""Small polygon operations on arrays of points (where shapely would need valid polygons)."""

from __future__ import annotations

import numpy as np


def clip_to_box(ring: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """A ring ``(N, 2)`` clipped to the box ``[x0, x1] x [y0, y1]`` (Sutherland and Hodgman:
    against each side in turn, keeping the points inside and each edge's crossing of the
    side). The part of the ring's area inside the box is unchanged; a ring that need not be
    simple (an annotation tool's) is clipped all the same."""
    ring = np.asarray(ring, np.float64).reshape(-1, 2)
    for axis, bound, keep_below in ((0, x0, False), (0, x1, True), (1, y0, False), (1, y1, True)):
        if len(ring) == 0:
            break
        out = []
        following = np.concatenate((ring[1:], ring[:1]))
        for p, q in zip(ring, following, strict=True):
            p_in = p[axis] <= bound if keep_below else p[axis] >= bound
            q_in = q[axis] <= bound if keep_below else q[axis] >= bound
            if p_in:
                out.append(p)
            if p_in != q_in:
                t = (bound - p[axis]) / (q[axis] - p[axis])
                out.append(p + t * (q - p))
        ring = np.array(out, np.float64).reshape(-1, 2)
    return ring
