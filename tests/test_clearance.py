"""Per-section distances on exact-geometry masks against shapely ground truth."""

from dataclasses import replace

import numpy as np
import pytest
import shapely

from harborsight.clearance import ClearanceSettings, measure_clearance
from harborsight.clearance.obstacles import SHIP, WATER
from harborsight.errors import InputError
from harborsight.geometry.camera import CameraIntrinsics
from harborsight.sim.schematic import ground_truth, render, sample_scene
from harborsight.vessel.spec import VesselSpec
from tests.helpers import flat_box_vessel


def errors_px(vessel, scene, method="ground_plane", own_rim_px=0):
    """(error in GSD pixels, contact flag) of every section measured and true in view."""
    _, labels, _ = render(scene)
    truth = ground_truth(scene)["sections"]
    report = measure_clearance(labels, scene.geometry(), vessel,
                               ClearanceSettings(method=method, own_rim_px=own_rim_px))
    rows = []
    for s, t in zip(report.sections, truth, strict=True):
        if s.status == "out_of_view":
            continue
        # every section in view agrees on whether an obstacle is in its band
        assert (s.status == "ok") == (t["distance_m"] is not None), (s, t)
        if s.status == "ok":
            rows.append(((s.distance_m - t["distance_m"]) / report.gsd_m_per_px, s.contact))
    return rows, report


@pytest.mark.parametrize("altitude_m", [30, 60, 90, 120, 150])
@pytest.mark.parametrize("scenario", ["alongside", "slip", "open"])
def test_nadir_within_one_gsd_pixel(altitude_m, scenario):
    vessel = flat_box_vessel()
    for method in ("ground_plane", "gsd"):
        rows = []
        for seed in range(altitude_m, altitude_m + 5):  # low open-water views may show no buoy
            rng = np.random.default_rng(seed)
            scene = sample_scene(vessel, rng, altitude_m=altitude_m, scenario=scenario)
            rows += errors_px(vessel, scene, method)[0]
            if len(rows) >= 3:
                break
        assert rows, "the scenes must have measurable sections"
        worst = max(abs(e) for e, _ in rows)
        assert worst <= 1.0, f"{method}: worst error {worst:.2f} px"


def test_tilted_ground_plane_within_1_5_px_and_gsd_worse():
    vessel = flat_box_vessel()
    errs = {"ground_plane": [], "gsd": []}
    for i, (altitude_m, tilt) in enumerate([(30, 10), (60, 15), (90, 20), (120, 12), (150, 18)]):
        for method in errs:
            rng = np.random.default_rng(100 + i)
            scene = sample_scene(vessel, rng, altitude_m=altitude_m, tilt_deg=tilt,
                                 scenario=["alongside", "slip"][i % 2])
            errs[method] += [e for e, _ in errors_px(vessel, scene, method)[0]]
    gp, gsd = np.abs(errs["ground_plane"]), np.abs(errs["gsd"])
    assert gp.max() <= 1.5
    assert gsd.mean() > 3 * gp.mean() and gsd.max() > 2.0


@pytest.mark.parametrize("own_rim_px", [0, 6])
@pytest.mark.parametrize("altitude_m", [45, 90, 140])
def test_touching_neighbour_only_affects_its_own_sections(altitude_m, own_rim_px):
    """Also with the own-vessel rim on: a touching neighbour is thicker than the rim, so it
    still reads (almost) zero at the hull."""
    vessel = flat_box_vessel()
    rng = np.random.default_rng(7)
    scene = sample_scene(vessel, rng, altitude_m=altitude_m, scenario="touching")
    rows, report = errors_px(vessel, scene, own_rim_px=own_rim_px)
    truth = ground_truth(scene)["sections"]
    margin = ClearanceSettings().pose_margin_px
    contact = [s for s in report.sections if s.contact]
    assert contact, "the sections facing the neighbour are flagged"
    for s in contact:
        t = truth[s.index]["distance_m"]
        # an upper bound on the gap, no worse than the own-vessel margin
        assert t - 0.5 * report.gsd_m_per_px <= s.distance_m <= t + (margin + 1) * report.gsd_m_per_px
    free = [e for e, c in rows if not c]
    assert max(abs(e) for e in free) <= 1.0
    far = [s for s in report.sections if s.status == "clear" or (s.distance_m or 0) > 1.0]
    assert len(far) >= report.sections.__len__() // 3  # the rest of the hull is not at zero


def test_statuses_and_vessel_out_of_frame():
    vessel = flat_box_vessel()
    rng = np.random.default_rng(2)
    scene = sample_scene(vessel, rng, altitude_m=25, scenario="open")
    _, labels, _ = render(scene)
    report = measure_clearance(labels, scene.geometry(), vessel)
    statuses = {s.status for s in report.sections}
    assert "clear" in statuses  # open water around most of the hull
    for s in report.sections:
        assert (s.distance_m is None) == (s.status != "ok")
        assert (s.status == "out_of_view") == (s.visible_fraction == 0)
    scene.uav_enu = scene.uav_enu + np.array([500.0, 0.0, 0.0])
    with pytest.raises(InputError, match="vessel: no part of the hull outline is in the image"):
        measure_clearance(labels, scene.geometry(), vessel)


def test_enclosed_basin_is_an_obstacle():
    """The inner border of solid ground around the vessel counts (RETR_LIST, not EXTERNAL)."""
    from shapely.geometry import box

    from harborsight.sim.schematic import Footprint

    vessel = flat_box_vessel(8)
    rng = np.random.default_rng(0)
    scene = sample_scene(vessel, rng, altitude_m=150, scenario="open")
    basin = box(-60, -60, 60, 60).difference(box(-45, -45, 45, 45))
    scene.footprints = [Footprint(basin, 2, 5, "quay", (120, 120, 120))]
    rows, report = errors_px(vessel, scene)
    assert sum(s.status == "ok" for s in report.sections) >= 6
    assert max(abs(e) for e, _ in rows) <= 1.0


def test_image_border_is_not_an_obstacle():
    vessel = flat_box_vessel()
    scene = sample_scene(vessel, np.random.default_rng(4), altitude_m=40, scenario="open")
    scene.footprints = []
    labels = np.zeros((360, 640), np.uint8)
    _, labels_vessel, _ = render(scene)
    labels[labels_vessel == 1] = 1
    report = measure_clearance(labels, scene.geometry(), vessel)
    assert all(s.status in ("clear", "out_of_view") for s in report.sections)


def test_a_clear_section_says_how_far_its_band_was_seen():
    """``clear_to_m``: nothing solid lies nearer, and the band leaves the picture there.
    Checked with shapely: the image's footprint on the water (its four corner pixels
    back-projected; a pinhole maps the border to straight lines on the plane) and the band
    of each section on a straight side (the strip between the normals at its ends); the
    distance from the section to the part of its strip outside the footprint."""
    from shapely.geometry import LineString, Polygon

    vessel = flat_box_vessel()
    scene = sample_scene(vessel, np.random.default_rng(4), altitude_m=40, scenario="open")
    scene.footprints = []
    _, rendered, _ = render(scene)
    labels = np.where(rendered == SHIP, SHIP, WATER).astype(np.uint8)
    geometry = scene.geometry()
    assert not geometry.camera.intrinsics.has_distortion
    report = measure_clearance(labels, geometry, vessel)
    h, w = labels.shape
    corners, ok = geometry.pixels_to_vessel_xy(np.array([[0.0, 0], [w - 1, 0], [w - 1, h - 1],
                                                          [0, h - 1]]))
    assert ok.all()
    footprint = Polygon(corners)
    outline = vessel.sections(16)
    checked = 0
    for s in report.sections:
        if s.status != "clear":
            continue
        assert s.clear_to_m is not None and s.clear_to_m >= 0.0
        k = s.index
        start, end = outline.break_points[k], outline.break_points[(k + 1) % len(outline.break_points)]
        edge = outline.break_edge[k]
        if outline.break_edge[(k + 1) % len(outline.break_edge)] != edge:
            continue                                  # a corner inside: not a plain strip
        normal = outline.edge_normal[edge]
        strip = Polygon([start, end, end + 500 * normal, start + 500 * normal])
        outside = strip.difference(footprint)
        expected = LineString([start, end]).distance(outside)
        # the border is sampled every 2 px: at most a pixel's ground size farther
        assert expected - 1e-6 <= s.clear_to_m <= expected + 1.5 * report.gsd_m_per_px, (k, expected)
        checked += 1
    assert checked >= 4
    assert all(s.clear_to_m is None for s in report.sections if s.status != "clear")


def test_an_obstacle_beyond_where_its_band_leaves_the_picture_bounds_the_section_by_that():
    """A quay face 15 m off, turned 35 degrees from the hull: a section near the stern sees
    it 12 m out through the part of its band still in the picture, while the rest of the
    band leaves the picture 8 m out, where a nearer obstacle could lie unseen. That
    section carries how far its band was seen (``clear_to_m``, checked
    with shapely as for a clear section) and its lower bound is at most that; the sections
    whose bands are seen out to the quay carry neither."""
    from shapely.geometry import LineString, Polygon

    from harborsight.sim.schematic import Footprint

    vessel = flat_box_vessel()
    scene = sample_scene(vessel, np.random.default_rng(4), altitude_m=40, scenario="open")
    geometry = scene.geometry()
    heading = geometry.vessel_heading_rad
    face = heading - np.radians(35.0)
    along = np.array([np.sin(face), np.cos(face)])
    out = np.array([np.cos(face), -np.sin(face)])
    starboard = np.array([np.cos(heading), -np.sin(heading)])
    centre = np.asarray(geometry.vessel_position_enu[:2]) + 15.0 * starboard
    quay = Polygon([centre - 300 * along, centre + 300 * along, centre + 300 * along + 50 * out,
                    centre - 300 * along + 50 * out])
    scene.footprints = [Footprint(quay, 2, 5, "quay", (120, 120, 120))]
    _, labels, _ = render(scene)
    report = measure_clearance(labels, geometry, vessel)
    h, w = labels.shape
    corners, _ = geometry.pixels_to_vessel_xy(np.array([[0.0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]]))
    footprint = Polygon(corners)
    outline = vessel.sections(16)
    ok = [s for s in report.sections if s.status == "ok"]
    short = [s for s in ok if s.clear_to_m is not None]
    assert len(short) == 1 and len(ok) >= 5
    s = short[0]
    assert s.clear_to_m < s.distance_m - 3.0
    assert s.distance_lower_m <= s.clear_to_m
    # the overlay's colour goes by the obstacle seen (as the live alarm), not the unseen part
    from harborsight.viz.overlay import alarm_distance_m

    assert alarm_distance_m(s) == pytest.approx(s.distance_m - 1.645 * s.sigma_m)
    assert alarm_distance_m(s) > s.clear_to_m
    k = s.index
    start, end = outline.break_points[k], outline.break_points[(k + 1) % len(outline.break_points)]
    normal = outline.edge_normal[outline.break_edge[k]]
    assert outline.break_edge[(k + 1) % len(outline.break_edge)] == outline.break_edge[k]
    strip = Polygon([start, end, end + 500 * normal, start + 500 * normal])
    expected = LineString([start, end]).distance(strip.difference(footprint))
    assert expected - 1e-6 <= s.clear_to_m <= expected + 1.5 * report.gsd_m_per_px
    for other in ok:
        if other is not s:
            assert other.distance_lower_m > other.distance_m - 2 * other.sigma_m


@pytest.mark.parametrize("seed, scenario", [(0, "open"), (1, "slip")])
def test_a_band_that_leaves_the_view_through_a_lens_fold_is_seen_only_that_far(seed, scenario):
    """A wide barrel lens (k1 = -0.34 at fx 300 px) folds inside a 640x360 image: half its
    pixels have no ray, and no pixel shows the water past the fold. A band that leaves the
    view there is seen only to the fold's edge: every ``clear`` section's ``clear_to_m``,
    and every ``ok`` section's lower bound, is at most how far its band is seen. Checked
    with shapely: the outline of every pixel that has a ray, back-projected, against each
    section's strip on the box's straight sides. The image's border alone had them seen on
    to the horizon or the far border (clear "to 81.9 m" and unbounded where the band left
    the view 27-35 m out) and, in the slip, a section reading a quay 52 m off kept a lower
    bound of 48.7 m where its band left the view 11 m out."""
    import cv2
    from shapely.geometry import LineString, Polygon

    vessel = flat_box_vessel()
    intr = CameraIntrinsics(640, 360, 300.0, 300.0, 319.5, 179.5, (-0.34, 0.0, 0.0, 0.0, 0.0))
    scene = sample_scene(vessel, np.random.default_rng(seed), altitude_m=40, scenario=scenario,
                         intrinsics=intr)
    _, labels, _ = render(scene)
    geometry = scene.geometry()
    report = measure_clearance(labels, geometry, vessel)
    grid = np.stack(np.meshgrid(np.arange(640.0), np.arange(360.0)), -1).reshape(-1, 2)
    has_ray = np.isfinite(geometry.camera.normalized_coordinates(grid)).all(axis=1).reshape(360, 640)
    assert 0.4 < has_ray.mean() < 0.6
    contours, _ = cv2.findContours(np.pad(has_ray.astype(np.uint8), 1), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    edge_px = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(float) - 1
    edge_v, on_water = geometry.pixels_to_vessel_xy(edge_px)
    seen = Polygon(edge_v[on_water]).buffer(0)
    outline = vessel.sections(16)
    checked = set()
    for s in report.sections:
        k = s.index
        start, end = outline.break_points[k], outline.break_points[(k + 1) % 16]
        if outline.break_edge[(k + 1) % 16] != outline.break_edge[k] or s.status not in ("clear", "ok"):
            continue                                # a corner inside: not a plain strip
        normal = outline.edge_normal[outline.break_edge[k]]
        strip = Polygon([start, end, end + 500 * normal, start + 500 * normal])
        reach = LineString([start, end]).distance(strip.difference(seen))
        # the edge is sampled every 2 px, on pixels up to 2 px inside it, where a pixel
        # spans metres near the fold
        tolerance = 0.03 * reach + 1.5 * report.gsd_m_per_px
        if s.status == "clear":
            assert s.clear_to_m is not None and s.clear_to_m <= reach + tolerance, (k, reach)
        else:
            assert s.distance_lower_m <= reach + tolerance, (k, reach, s.distance_m)
        checked.add(s.status)
    assert checked == ({"clear", "ok"} if scenario == "open" else {"ok"})


def test_obstacle_corner_poking_less_than_a_pixel_into_a_band():
    """A wedge whose tip enters section k's band by 0.3 px leaves no pixel centre there; the
    pixel squares that reach across the break still give section k its (true) distance."""
    import shapely
    from shapely.geometry import Polygon

    from harborsight.sim.schematic import Footprint

    vessel = flat_box_vessel()
    rng = np.random.default_rng(0)
    scene = sample_scene(vessel, rng, altitude_m=100, scenario="open")
    geometry = scene.geometry()
    sections = vessel.sections()
    # a break on a straight side: its ray is the side's normal
    k = next(i for i in range(1, sections.n_sections)
             if abs(sections.break_ray[i] @ sections.edge_dir[sections.break_edge[i]]) < 1e-9
             and sections.break_edge[i - 1] == sections.break_edge[i]
             and sections.break_points[i, 1] > 0)
    origin, ray = sections.break_points[k], sections.break_ray[k]
    tangent = sections.edge_dir[sections.break_edge[k]]   # into section k
    gsd_m = 100.0 / scene.intrinsics.fx
    gap_m = 7.0
    tip = origin + gap_m * ray + 0.3 * gsd_m * tangent
    wedge_v = np.array([tip, tip - 8.0 * tangent, tip - 8.0 * tangent + 10.0 * ray])
    wedge = Polygon(geometry.vessel_to_enu(wedge_v)[:, :2])
    scene.footprints = [Footprint(wedge, 2, 5, "quay", (120, 120, 120))]
    _, labels, _ = render(scene)
    truth = ground_truth(scene)["sections"]
    assert truth[k]["distance_m"] == pytest.approx(gap_m, abs=1e-6)

    # precondition: no solid pixel centre lies in section k's band
    rows, cols = np.nonzero(labels == 2)
    solid_v, _ = geometry.pixels_to_vessel_xy(np.column_stack((cols, rows)).astype(float))
    assert k - 1 in set(sections.assign(solid_v).section.tolist())
    assert k not in set(sections.assign(solid_v).section.tolist())
    assert not shapely.contains_xy(wedge, *geometry.vessel_to_enu(
        sections.section_polyline(k))[:, :2].T).any()

    report = measure_clearance(labels, geometry, vessel)
    measured = report.sections[k]
    assert measured.status == "ok"
    assert abs(measured.distance_m - gap_m) <= 1.0 * report.gsd_m_per_px
    # the section that holds the wedge is unchanged by its neighbour's candidates
    assert abs(report.sections[k - 1].distance_m - truth[k - 1]["distance_m"]) \
        <= 1.0 * report.gsd_m_per_px


def test_own_rim_removes_thin_ship_slivers_only():
    """Hand-made mask: own region rows 40-59, cols 40-119. A 3 px ship-class sliver on its
    top edge is the model's spill; a 3 px obstacle-class sliver on its bottom edge is a real
    (thin) solid; a 30 px ship touches its right end."""
    from harborsight.clearance.obstacles import OwnRegion, obstacle_contours, own_rim

    labels = np.zeros((100, 200), np.uint8)
    own_mask = np.zeros_like(labels)
    own_mask[40:60, 40:120] = 255
    own = OwnRegion(own_mask, (slice(40, 60), slice(40, 120)))
    labels[40:60, 40:120] = 1
    labels[37:40, 45:115] = 1      # ship-class spill, 3 px thick
    labels[60:63, 45:115] = 2      # obstacle-class sliver, 3 px thick
    labels[30:70, 120:150] = 1     # a touching ship, 30 px wide

    rim = own_rim(labels, own, 4) > 0
    assert rim[37:40, 45:115].all()
    assert not rim[60:63].any() and not rim[:, 120:].any()
    assert not own_rim(labels, own, 0).any()

    def rows_cols(contours):
        return set(map(tuple, contours.points_px[:, ::-1].tolist()))

    plain, trimmed = obstacle_contours(labels, own), obstacle_contours(labels, own, 4)
    assert any(r == 37 for r, _ in rows_cols(plain))          # spill read as an obstacle
    assert not any(r < 40 and c < 120 for r, c in rows_cols(trimmed))
    assert any(r == 62 for r, _ in rows_cols(trimmed))        # the thin obstacle stays
    touching = {(r, c) for r, c in rows_cols(trimmed) if c == 120 and 40 <= r < 60}
    assert touching, "the neighbour keeps its edge at the hull"
    idx = [i for i, (u, v) in enumerate(trimmed.points_px) if u == 120 and 40 <= v < 60]
    assert trimmed.contact[idx].all()
    # a sliver thicker than the rim is a neighbour, not spill (the opening rounds off at
    # most its corner pixels)
    labels[30:40, 45:115] = 1
    assert not (own_rim(labels, own, 4)[30:40, 48:112] > 0).any()


def test_two_sections_take_a_band_edge_sliver_at_the_right_break():
    """With two sections both breaks (bow and stern tips) separate the same two bands, and
    a box's two break rays lie on one line. A wedge whose tip pokes 0.3 px across the bow
    ray must be measured at the bow, as with three sections, not at the stern tip 40 m
    away."""
    from shapely.geometry import Polygon

    from harborsight.sim.schematic import Footprint

    results = {}
    for n in (2, 3):
        vessel = flat_box_vessel(n)
        scene = sample_scene(vessel, np.random.default_rng(0), altitude_m=100, scenario="open")
        geometry = scene.geometry()
        gsd_m = 100.0 / scene.intrinsics.fx
        tip = np.array([37.0, 0.3 * gsd_m])
        wedge = tip + np.array([[0.0, 0.0], [5.0, -5.0], [0.0, -10.0], [-5.0, -5.0]])
        scene.footprints = [Footprint(Polygon(geometry.vessel_to_enu(wedge)[:, :2]), 2, 5,
                                      "quay", (120, 120, 120))]
        _, labels, _ = render(scene)
        truth = ground_truth(scene)["sections"][0]["distance_m"]
        report = measure_clearance(labels, geometry, vessel, ClearanceSettings(own_rim_px=0))
        results[n] = report.sections[0].distance_m
        assert results[n] == pytest.approx(truth, abs=2 * gsd_m)
    assert results[2] == pytest.approx(results[3])


def test_wide_barrel_lens_keeps_the_vessel_inside_its_own_region():
    """k1 = -0.2 bends the straight sides of a 40 m vessel with an 8 m high deck by up to
    10 px when it fills a wide (90 degree) view from 28 m. The mask holds nothing but the
    vessel, each pixel marked where its undistorted ray falls inside the pinhole image of
    the vessel's convex hull, so every section must be clear. The hull of the projected
    corners alone cut the bent sides off (5,745 vessel pixels outside it), and the deck's
    edge then read as an obstacle 0.4-1.5 m off 12 of the 16 sections."""
    flat = flat_box_vessel()
    deck = np.column_stack((flat.outline, np.full(len(flat.outline), -8.0)))  # z down
    vessel = VesselSpec("decked", flat.outline, np.vstack((flat.hull_points, deck)), 16)
    intr = CameraIntrinsics(640, 360, 320.0, 320.0, 319.5, 179.5, (-0.2, 0.0, 0.0, 0.0, 0.0))
    scene = sample_scene(vessel, np.random.default_rng(5), altitude_m=28, scenario="open",
                         intrinsics=intr)
    camera = scene.geometry().camera
    hull_c = camera.to_camera_frame(scene.geometry().vessel_to_enu(vessel.hull_points))
    image_of_hull = shapely.MultiPoint(hull_c[:, :2] / hull_c[:, 2:3]).convex_hull
    grid = np.stack(np.meshgrid(np.arange(640.0), np.arange(360.0)), -1).reshape(-1, 2)
    rays = camera.normalized_coordinates(grid)
    on_vessel = shapely.contains_xy(image_of_hull, *np.nan_to_num(rays, nan=1e9).T)
    labels = np.where(on_vessel, SHIP, WATER).astype(np.uint8).reshape(360, 640)
    assert 0.2 < on_vessel.mean() < 0.9
    report = measure_clearance(labels, scene.geometry(), vessel)
    assert {s.status for s in report.sections} <= {"clear", "out_of_view"}


def _rim_over_the_whole_box(labels, own, rim_px):
    """own_rim's formula computed over the region's whole box grown by 2r + 1 (how it was
    first written, before it looked only at the ship pixels within r of the region)."""
    import cv2

    from harborsight.clearance.obstacles import _grown_slices

    rim = np.zeros(labels.shape, np.uint8)
    if rim_px <= 0 or own.bbox is None:
        return rim
    roi = _grown_slices(own.bbox, 2 * rim_px + 1, labels.shape)
    ship_outside = np.where((labels[roi] == SHIP) & (own.mask[roi] == 0), 255, 0).astype(np.uint8)
    diameter = 2 * int(np.ceil(rim_px / 2)) + 1
    thick = cv2.morphologyEx(ship_outside, cv2.MORPH_OPEN,
                             cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter, diameter)))
    near_own = cv2.dilate(own.mask[roi], cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * rim_px + 1, 2 * rim_px + 1)))
    rim[roi] = ship_outside & near_own & ~thick
    return rim


def test_own_rim_looks_only_near_the_region_and_finds_the_whole_rim():
    """Random masks and regions (near and across the image's edges, margins 0 to 3.5 px,
    rims 0 to 7 px): own_rim, which opens and dilates only around the box of its candidates
    as they narrow (and nothing once there are none), equals the formula over the whole
    search box."""
    import cv2

    from harborsight.clearance.obstacles import own_rim, own_vessel_region

    rng = np.random.default_rng(5)
    found = skipped = 0
    for trial in range(400):
        h, w = int(rng.integers(20, 120)), int(rng.integers(20, 160))
        labels = rng.choice([0, 1, 2, 255], size=(h, w), p=[0.6, 0.25, 0.1, 0.05]).astype(np.uint8)
        if trial % 2:
            labels = cv2.medianBlur(labels, 3)      # blobs and slivers rather than speckle
        if trial % 5 == 0:                          # ship pixels only far from the region
            labels[labels == SHIP] = WATER
            labels[:4, :4] = SHIP
        centre = rng.uniform([-20, -20], [w + 20, h + 20]) if trial % 5 else np.array([w - 8.0, h - 8.0])
        own = own_vessel_region(centre + rng.normal(0, rng.uniform(2, 20), (6, 2)), labels.shape,
                                float(rng.choice([0, 1, 2, 3.5])))
        rim_px = int(rng.integers(0, 8))
        rim = own_rim(labels, own, rim_px)
        expected = _rim_over_the_whole_box(labels, own, rim_px)
        assert rim.dtype == np.uint8 and np.array_equal(rim, expected), trial
        found += bool(expected.any())
        skipped += trial % 5 == 0 and own.bbox is not None and rim_px > 0
    assert found > 150 and skipped > 50


def test_own_region_dilated_over_a_wider_window_is_the_same():
    """own_vessel_region dilates a window widened to whole SIMD blocks of columns: random
    polygons, in and across the image's edges, give the mask and box of the polygon's box
    dilated alone."""
    import cv2

    from harborsight.clearance.obstacles import _grown_bbox, own_vessel_region

    rng = np.random.default_rng(7)
    for trial in range(600):
        h, w = int(rng.integers(10, 200)), int(rng.integers(10, 300))
        centre = rng.uniform([-30, -30], [w + 30, h + 30])
        corners = centre + rng.normal(0, rng.uniform(0.5, 40), (int(rng.integers(3, 12)), 2))
        margin = float(rng.choice([0, 0.4, 1, 2, 3.5, 6]))
        own = own_vessel_region(corners, (h, w), margin)
        expected = np.zeros((h, w), np.uint8)
        hull = cv2.convexHull(np.round(corners * 16).astype(np.int32))
        cv2.fillConvexPoly(expected, hull, 255, lineType=cv2.LINE_8, shift=4)
        radius = int(np.ceil(margin))
        box = _grown_bbox(hull.reshape(-1, 2) / 16, radius + 1, (h, w))
        if radius > 0 and box is not None:
            disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
            expected[box] = cv2.dilate(expected[box], disk)
        assert own.bbox == box and np.array_equal(own.mask, expected), trial


def test_windows_widen_to_whole_simd_blocks_inside_the_image():
    from harborsight.clearance.obstacles import _SIMD_COLUMNS, _simd_wide

    rng = np.random.default_rng(3)
    for _ in range(500):
        width = int(rng.integers(1, 400))
        start = int(rng.integers(0, width))
        stop = int(rng.integers(start + 1, width + 1))
        rows = slice(2, 9)
        wide_rows, wide = _simd_wide((rows, slice(start, stop)), (50, width))
        assert wide_rows == rows and 0 <= wide.start <= start and stop <= wide.stop <= width
        assert wide.stop - wide.start == min(-(-(stop - start) // _SIMD_COLUMNS) * _SIMD_COLUMNS, width)


def test_own_rim_near_its_reach():
    """Hand-made edge cases of own_rim's windows (region rows 40-59, cols 40-119, r = 4):
    a lone ship pixel exactly r above the region is rim (its dilation window must reach r
    back to the region), and a 4-row strip from 3 to 6 rows above it is too thin for the
    opening's disk, though only its two nearest rows lie within r of the region's box (the
    opening's window must reach 2⌈r/2⌉ past them, to the water beyond the strip)."""
    from harborsight.clearance.obstacles import OwnRegion, own_rim

    own_mask = np.zeros((100, 200), np.uint8)
    own_mask[40:60, 40:120] = 255
    own = OwnRegion(own_mask, (slice(40, 60), slice(40, 120)))
    for rows in (slice(36, 37), slice(34, 38)):
        labels = np.zeros((100, 200), np.uint8)
        labels[40:60, 40:120] = SHIP
        labels[rows, 60:100] = SHIP if rows.stop - rows.start > 1 else WATER
        labels[36, 80] = SHIP
        rim = own_rim(labels, own, 4)
        assert np.array_equal(rim, _rim_over_the_whole_box(labels, own, 4))
        assert rim[36, 80] == 255 and not rim[:36].any()


def test_a_refined_pose_places_the_sections_and_their_sigmas_anew():
    """The hull 2.3 m and 2.5 degrees off, partly out of view: with the refined pose applied,
    every section's visible share and end pixels, the sigmas (from the outline's pixels
    under that pose) and the gsd method's outline are those of the refined pose, computed
    here on their own, not the sensors' pose's (which differ)."""
    from dataclasses import replace

    from harborsight.clearance.measure import alignment_settings
    from harborsight.clearance.pose_refinement import corrected_geometry, refine_vessel_pose
    from harborsight.clearance.uncertainty import add_section_uncertainty

    vessel = flat_box_vessel()
    scene = sample_scene(vessel, np.random.default_rng(0), altitude_m=22, tilt_deg=8,
                         scenario="alongside")
    _, labels, _ = render(scene)
    off = corrected_geometry(scene.geometry(), np.array([1.8, -1.5, np.radians(2.5)]))
    settings = ClearanceSettings()
    report = measure_clearance(labels, off, vessel, settings)
    assert report.pose_refinement["applied"]
    refined, refinement = refine_vessel_pose(labels, off, vessel,
                                             alignment_settings(settings, settings.sensor_sigmas(),
                                                                float(off.camera.position_enu[2])))
    sections_v = vessel.sections()
    n = sections_v.n_sections
    points, section = sections_v.samples(16 * n)

    def in_view(geometry):
        uv = geometry.camera.project(geometry.vessel_to_enu(points))[0]
        share = np.bincount(section, weights=geometry.camera.in_image(uv), minlength=n)
        ends = geometry.camera.project(geometry.vessel_to_enu(
            sections_v.section_endpoints().reshape(-1, 2)))[0].reshape(n, 2, 2)
        return share / np.bincount(section, minlength=n), ends

    share, ends = in_view(refined)
    share_off, ends_off = in_view(off)
    assert np.abs(share - share_off).max() > 0.5 and np.abs(ends - ends_off).max() > 5
    assert ((share > 0) & (share < 1)).any() and (share == 0).any()
    np.testing.assert_allclose([s.visible_fraction for s in report.sections], share, atol=1e-12)
    np.testing.assert_allclose([s.hull_px for s in report.sections], ends, atol=1e-9)
    ok = [s for s in report.sections if s.status == "ok"]
    assert len(ok) >= 3
    again = [replace(s, sigma_m=None, sigma_random_m=None, distance_lower_m=None) for s in ok]
    add_section_uncertainty(again, refined, refined.vessel_to_enu(sections_v.vertices), refinement,
                            settings.sensor_sigmas(), labels=labels,
                            vessel_points_enu=refined.vessel_to_enu(vessel.hull_points))
    for field in ("sigma_m", "sigma_random_m"):
        np.testing.assert_allclose([getattr(s, field) for s in ok],
                                   [getattr(s, field) for s in again], rtol=1e-12)
    # a section whose band leaves the picture nearer than its obstacle is bounded by that
    assert any(s.clear_to_m is not None for s in ok)
    np.testing.assert_allclose([s.distance_lower_m for s in ok],
                               [min(a.distance_lower_m, s.clear_to_m if s.clear_to_m is not None else np.inf)
                                for s, a in zip(ok, again, strict=True)], rtol=1e-12)
    # the gsd method's outline in pixels is the refined pose's too: each hull point lies on
    # its section of it
    gsd = measure_clearance(labels, off, vessel, ClearanceSettings(method="gsd"))
    assert gsd.pose_refinement["applied"]

    def off_its_section(geometry):
        in_pixels = sections_v.transformed(
            lambda points: geometry.camera.project(geometry.vessel_to_enu(points))[0])
        return [shapely.LineString(in_pixels.section_polyline(s.index)).distance(
            shapely.Point(s.hull_point_px)) for s in gsd.sections if s.status == "ok"]

    assert len(off_its_section(refined)) >= 3 and max(off_its_section(refined)) < 1e-9
    assert max(off_its_section(off)) > 5


def _pile_beside_a_break(offset_m: float, quay_m: float | None = None):
    """An open scene 60 m up with one pile (0.8 m square) 4 m out along the boundary ray of
    a break on a straight side, ``offset_m`` into the band before it; with ``quay_m``, a
    quay face that far out across the band after it. Returns (vessel, scene, labels, k,
    distance of the pile's nearest corner from the break)."""
    from shapely.geometry import Polygon

    from harborsight.sim.schematic import Footprint

    vessel = flat_box_vessel()
    scene = sample_scene(vessel, np.random.default_rng(0), altitude_m=60, scenario="open")
    geometry = scene.geometry()
    sections = vessel.sections()
    k = next(i for i in range(1, sections.n_sections)
             if abs(sections.break_ray[i] @ sections.edge_dir[sections.break_edge[i]]) < 1e-9
             and sections.break_edge[i - 1] == sections.break_edge[i]
             and sections.break_edge[(i + 1) % sections.n_sections] == sections.break_edge[i])
    origin, ray = sections.break_points[k], sections.break_ray[k]
    tangent = sections.edge_dir[sections.break_edge[k]]            # into section k
    near = origin + 4.0 * ray - offset_m * tangent
    pile_v = np.array([near, near - 0.8 * tangent, near - 0.8 * tangent + 0.8 * ray,
                       near + 0.8 * ray])
    footprints = [Footprint(Polygon(geometry.vessel_to_enu(pile_v)[:, :2]), 2, 5, "pile",
                            (90, 90, 90))]
    if quay_m is not None:
        quay_v = np.array([origin + quay_m * ray + 0.5 * tangent, origin + quay_m * ray + 6 * tangent,
                           origin + (quay_m + 5) * ray + 6 * tangent,
                           origin + (quay_m + 5) * ray + 0.5 * tangent])
        footprints.append(Footprint(Polygon(geometry.vessel_to_enu(quay_v)[:, :2]), 2, 6,
                                    "quay", (120, 120, 120)))
    scene.footprints = footprints
    _, labels, _ = render(scene)
    return vessel, scene, labels, k, float(np.hypot(*(near - origin)))


def test_an_obstacle_an_unconfirmed_pose_may_put_in_a_band_bounds_what_it_says():
    """A pile 0.3 m into the neighbouring band, 4 m out: with the sensors' pose unchecked by
    the image (refinement off) and standalone GPS and compasses, the pile may lie in this
    band, so a clear band is seen clear only to it, and an ok band reading a quay 8 m out
    has its lower bound at it; with RTK and a 0.2 degree compass it may not, and the band is
    seen on; a pose the image placed is not widened (clearance.band_margin)."""
    from harborsight.clearance.pose_refinement import SENSORS_FIT, PoseRefinementSettings

    off = ClearanceSettings(pose_refinement=PoseRefinementSettings(enabled=False))
    rtk = (("uav_gps", 0.02), ("vessel_gps", 0.02), ("vessel_heading_deg", 0.2),
           ("camera_yaw_deg", 0.2), ("camera_tilt_deg", 0.05), ("height_m", 0.05))
    vessel, scene, labels, k, pile_m = _pile_beside_a_break(0.3)
    geometry = scene.geometry()
    truth = ground_truth(scene)["sections"]
    assert truth[k]["distance_m"] is None and truth[k - 1]["distance_m"] is not None

    loose = measure_clearance(labels, geometry, vessel, off).sections
    assert loose[k - 1].status == "ok"
    assert loose[k].status == "clear"
    assert loose[k].clear_to_m == pytest.approx(pile_m, abs=0.15)
    seen_m = measure_clearance(np.where(labels == 2, WATER, labels).astype(np.uint8), geometry,
                               vessel, off).sections[k].clear_to_m       # where it leaves the picture
    assert seen_m > pile_m + 3.0
    tight = measure_clearance(labels, geometry, vessel, replace(off, sigma_options=rtk)).sections
    assert tight[k].status == "clear" and tight[k].clear_to_m == seen_m
    placed = measure_clearance(labels, geometry, vessel)
    assert placed.pose_refinement["applied"] or placed.pose_refinement["reason"] == SENSORS_FIT
    assert placed.sections[k].clear_to_m == pytest.approx(seen_m, abs=0.01)

    vessel, scene, labels, k, pile_m = _pile_beside_a_break(0.3, quay_m=8.0)
    geometry = scene.geometry()
    loose = measure_clearance(labels, geometry, vessel, off).sections
    assert loose[k].status == "ok" and loose[k].distance_m == pytest.approx(8.0, abs=0.2)
    assert loose[k].distance_lower_m == pytest.approx(pile_m, abs=0.15)
    tight = measure_clearance(labels, geometry, vessel, replace(off, sigma_options=rtk)).sections
    assert tight[k].distance_lower_m > pile_m + 2.0        # the quay's own bound


def test_a_hull_placed_across_only_keeps_the_sensors_place_along_it_for_its_bands(monkeypatch):
    """The pile 0.3 m into the neighbouring band, with the pose refined but its place along
    the hull held at the sensors' (as when neither end of the hull is in view, here made
    so): the bands can still be off along the hull by the receivers' error, so the clear band
    is seen only to the pile with standalone GPS, and on to the picture's edge with RTK."""
    import harborsight.clearance.pose_refinement as pose_refinement
    from harborsight.clearance import band_margin

    vessel, scene, labels, k, pile_m = _pile_beside_a_break(0.3)
    geometry = scene.geometry()
    placed = measure_clearance(labels, geometry, vessel)
    assert not placed.pose_refinement["along_hull_held"]
    seen_m = placed.sections[k].clear_to_m
    assert seen_m > pile_m + 3.0
    monkeypatch.setattr(pose_refinement, "sees_along", lambda *args, **kwargs: False)
    held = measure_clearance(labels, geometry, vessel)
    assert held.pose_refinement["along_hull_held"]
    # placed (or confirmed) by the image: not the unconfirmed pose's margin, all the sensors'
    _, refinement = pose_refinement.refine_vessel_pose(labels, geometry, vessel)
    assert refinement.along_hull_held and not band_margin.pose_kept_unconfirmed(refinement)
    assert held.sections[k].status == "clear"
    assert held.sections[k].clear_to_m == pytest.approx(pile_m, abs=0.15)
    rtk = (("uav_gps", 0.02), ("vessel_gps", 0.02))
    tight = measure_clearance(labels, geometry, vessel, ClearanceSettings(sigma_options=rtk))
    assert tight.pose_refinement["along_hull_held"]
    assert tight.sections[k].clear_to_m == pytest.approx(seen_m, abs=0.01)
