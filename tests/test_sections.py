"""Band assignment (argmax of edge-line distances) against explicit shapely band polygons."""

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon

from harborsight.sim.ground_truth import section_band_polygon
from harborsight.vessel.outline import outline_from_dimensions
from harborsight.vessel.sections import SectionedOutline


def random_convex_polygon(rng, n=9):
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    pts = np.column_stack((20 * np.cos(angles), 7 * np.sin(angles)))
    hull = np.asarray(Polygon(pts).convex_hull.exterior.coords)[:-1]
    from harborsight.vessel.outline import convex_outline
    return convex_outline(hull)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n_sections", [1, 5, 16])
def test_assignment_matches_band_polygons(seed, n_sections):
    rng = np.random.default_rng(seed)
    outline = (outline_from_dimensions(30, 10, 4, 6) if seed == 0 else random_convex_polygon(rng))
    sections = SectionedOutline.split(outline, n_sections)
    hull = Polygon(outline)
    points = rng.uniform(-60, 60, (600, 2))
    result = sections.assign(points)
    inside = shapely.contains_xy(hull, points[:, 0], points[:, 1])
    assert (result.section[inside] == -1).all()
    bands = [section_band_polygon(sections, k) for k in range(n_sections)]
    for p, k, d in zip(points[~inside], result.section[~inside], result.distance[~inside],
                       strict=True):
        assert bands[k].buffer(1e-6).contains(shapely.Point(p)), (p, k)
        assert d == pytest.approx(shapely.distance(hull.exterior, shapely.Point(p)), abs=1e-9)
        line = LineString(sections.section_polyline(k))
        assert d == pytest.approx(line.distance(shapely.Point(p)), abs=1e-9)


def test_bow_wedge_split_on_bisector():
    sections = SectionedOutline.split(outline_from_dimensions(30, 10, 5, 5), 8)
    ahead = np.array([[40.0, 0.5], [40.0, -0.5]])
    assert sections.assign(ahead).section.tolist() == [0, 7]
