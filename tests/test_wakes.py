"""Wakes of boats under way: the white-water pattern by hand (astern, Kelvin arms, nothing
ahead), painted only on water pixels, and a render whose labels the wakes leave alone."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import trimesh

from harborsight.sim.dataset import FrameRenderer, SimulationConfig, plan_frame, prepare_vessels
from harborsight.sim.scene import SHIP, Part, SceneObject
from harborsight.sim.wakes import KELVIN_DEG, clear_track_m, paint_wakes, wake_intensity
from harborsight.vessel.spec import load_vessel_spec

STERN, BOW = np.array([0.0, -5.0]), np.array([0.0, 5.0])      # a 10 m boat heading north


def test_the_wake_lies_astern_along_the_track_and_on_the_kelvin_arms():
    assert pytest.approx(19.47, abs=0.01) == KELVIN_DEG
    def at(e, n):
        return float(wake_intensity(np.array([[e, n]]), STERN, BOW, 10.0, 3.0, 5.0)[0])
    assert at(0.0, -10.0) > 0.5                   # the turbulent wake, 5 m astern
    assert at(0.0, 20.0) == 0.0 and at(8.0, 8.0) == 0.0     # nothing ahead of the bow
    # 30 m astern of the bow, the arm is 30 tan(19.47°) = 10.6 m off the track
    arm = 30.0 * math.tan(math.radians(KELVIN_DEG))
    assert at(arm, 5.0 - 30.0) > 0.2 and at(-arm, 5.0 - 30.0) > 0.2
    assert at(arm, 5.0 - 30.0) > 20 * at(6.0, 5.0 - 30.0)    # between the arm and the centre
    # it fades with distance: 200 m astern there is almost nothing left
    assert at(0.0, -200.0) < 0.02


def test_wakes_are_painted_on_water_pixels_only(nadir_scene):
    """A 6 m boat heading along the image's -v (up) from the image's centre: the water below
    it (astern) turns whiter, the water above it does not, and a pixel that is not water
    keeps its colour even inside the wake."""
    scene = nadir_scene
    camera = scene.geometry().camera
    intr = scene.intrinsics
    centre, _ = camera.back_project_to_plane(np.array([[(intr.width - 1) / 2, (intr.height - 1) / 2],
                                                       [(intr.width - 1) / 2, 0.0]]))
    up = centre[1, :2] - centre[0, :2]
    course = math.degrees(math.atan2(up[0], up[1]))
    hull = trimesh.creation.box(extents=(6.0, 2.0, 1.0))
    hull.apply_transform(trimesh.transformations.rotation_matrix(math.radians(90 - course), (0, 0, 1)))
    hull.apply_translation((*centre[0, :2], 0.5))
    boat = SceneObject("boat", "boat", SHIP, 50, [Part(hull, "hull")], course_deg=course)
    scene = replace(scene, objects=[boat])           # alone: nothing astern to end its wake
    image = np.full((intr.height, intr.width, 3), 90, np.uint8)
    instances = np.zeros((intr.height, intr.width), np.uint16)
    cu, cv = intr.width // 2, intr.height // 2
    instances[cv - 1:cv + 2, cu - 2:cu + 3] = 50              # the boat's pixels
    instances[cv + 6, cu] = 7                                 # something on the water astern
    painted = paint_wakes(image, instances, scene, np.random.default_rng(0))
    gain = painted.astype(int).sum(axis=2) - image.astype(int).sum(axis=2)
    assert gain[cv + 3:cv + 12, cu - 1:cu + 2].mean() > 30     # astern: white water
    assert (gain[:cv - 6] == 0).all()        # ahead (beyond the 2-px grid's blur): untouched
    assert (gain[instances != 0] == 0).all()                   # not water: untouched
    # no boat under way: the image comes back as it was
    still = replace(scene, objects=[replace(boat, course_deg=None)])
    assert paint_wakes(image, instances, still, np.random.default_rng(0)) is image


def _frame_with_a_boat_under_way_in_view(config, vessels, tries: int = 80) -> int:
    """The first frame of ``config`` whose plan has a boat under way in the middle of the
    image (its centroid at least a fifth of the image in from every edge), found from the
    plans alone, so that changes to the families' draws never leave the test without one."""
    for index in range(tries):
        scene = plan_frame(config, index, vessels)
        camera, intr = scene.geometry().camera, scene.intrinsics
        for obj in scene.objects:
            if obj.course_deg is None:
                continue
            centre = obj.footprint().centroid
            uv, ok = camera.project(np.array([[centre.x, centre.y, 0.0]]))
            u, v = uv[0] / (intr.width, intr.height)
            if ok[0] and 0.2 < u < 0.8 and 0.2 < v < 0.8:
                return index
    raise AssertionError(f"no boat under way in view in frames 0-{tries - 1}")


def test_a_rendered_wake_changes_the_water_and_no_label(tmp_path):
    """A tiny lake-shore frame (seed 21) with a boat under way in view, rendered with and
    without wakes: the labels are the same, the water whiter. (Unmetered: the camera's
    metering would darken the whole frame a little for the white water, as a real one does.)"""
    config = SimulationConfig(seed=21, preset="tiny", vessel_pool=1, scenario="lakeshore",
                              auto_exposure=False, leisure_vessels=False)   # the scene as chosen
    vessels = {name: load_vessel_spec(path) for name, path in prepare_vessels(tmp_path, config).items()}
    index = _frame_with_a_boat_under_way_in_view(config, vessels)
    files = {}
    for wakes in (True, False):
        files[wakes] = FrameRenderer(tmp_path, replace(config, wakes=wakes)).render_files(index).files
    def decode(wakes, name):
        return cv2.imdecode(np.frombuffer(files[wakes][f"{name}/{index:06d}.png"], np.uint8),
                            cv2.IMREAD_UNCHANGED)
    assert np.array_equal(decode(True, "labels"), decode(False, "labels"))
    labels = decode(True, "labels")
    change = np.abs(decode(True, "images").astype(int) - decode(False, "images").astype(int)).max(axis=2)
    # the camera's blur and JPEG spread a little of the paint onto the neighbours; the
    # white water itself is on the water
    assert change.max() > 20
    assert change[labels == 0].sum() > 4 * change[labels != 0].sum()


def test_a_wake_ends_where_the_track_astern_meets_an_obstacle():
    from shapely.geometry import box

    pier = box(-5.0, -31.0, 5.0, -29.0)                 # across the track, 24-26 m astern
    beside = box(20.0, -60.0, 30.0, -40.0)              # off the track: no effect
    assert clear_track_m(STERN, BOW, 3.0, [pier, beside]) == pytest.approx(24.0, abs=0.02)
    assert clear_track_m(STERN, BOW, 3.0, [beside]) == 2000.0
    def at(n, clear):
        return float(wake_intensity(np.array([[0.0, n]]), STERN, BOW, 10.0, 3.0, 5.0, clear)[0])
    assert at(-20.0, 24.0) > 0.3 and at(-40.0, 24.0) == 0.0 and at(-40.0, np.inf) > 0.2
