"""Small builders shared by the tests."""

from __future__ import annotations

import numpy as np

from harborsight.vessel.outline import outline_from_dimensions
from harborsight.vessel.spec import VesselSpec


def flat_box_vessel(n_sections: int = 16) -> VesselSpec:
    """A 40 m x 10 m pointed-bow vessel with no height (the planar case)."""
    outline = outline_from_dimensions(30.0, 10.0, 5.0, 5.0)
    hull_points = np.column_stack((outline, np.zeros(len(outline))))
    return VesselSpec("test-boat", outline, hull_points, n_sections)
