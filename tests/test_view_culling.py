"""Out-of-view culling: which objects can change a frame (directly, by shadow, in reflection),
checked against hand-placed boxes; the renders with and without it share every label."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from harborsight.errors import InputError
from harborsight.sim.dataset import SimulationConfig, simulate
from harborsight.sim.scene import OBSTACLE, Part, SceneObject
from harborsight.sim.view_culling import light_directions, objects_in_view


def _box_object(name: str, centre_en: tuple[float, float], height_m: float) -> SceneObject:
    mesh = trimesh.creation.box(extents=(2.0, 2.0, height_m))
    mesh.apply_translation((centre_en[0], centre_en[1], height_m / 2))
    return SceneObject(name, "quay", OBSTACLE, 900 + len(name), [Part(mesh, "quay")])


def _image_x_axis_on_water(scene) -> tuple[np.ndarray, np.ndarray, float]:
    """The nadir ``(e, n)``, the unit direction on the water of the image's +x through it,
    and the distance from the nadir to the right edge along it (a nadir camera)."""
    camera = scene.geometry().camera
    intr = scene.intrinsics
    row = (intr.height - 1) / 2
    ground, _ = camera.back_project_to_plane(np.array([[(intr.width - 1) / 2, row],
                                                       [intr.width - 0.5, row]]))
    nadir, edge = ground[0, :2], ground[1, :2]
    return nadir, (edge - nadir) / np.linalg.norm(edge - nadir), float(np.linalg.norm(edge - nadir))


def test_objects_out_of_reach_are_left_out_and_those_in_reach_kept(nadir_scene):
    """Boxes on the image's middle row: one in view; one far off; a 10 m box 15 m beyond the
    left edge, whose shadow reaches 22 m into the view with the sun 15 degrees up behind it
    (its reflection, at (15 + half)·h/(h + 10) from the nadir, stays out); and the same box
    beyond the right edge, its shadow falling away. With the sun high, the left box goes."""
    scene = nadir_scene
    nadir, axis, half_m = _image_x_axis_on_water(scene)
    altitude_m = scene.geometry().camera.position_enu[2]
    assert (half_m + 14.0) * altitude_m / (altitude_m + 10.0) > half_m * 1.1   # reflection out

    def box(name: str, along_m: float, height_m: float) -> SceneObject:
        return _box_object(name, tuple(nadir + along_m * axis), height_m)

    # the sun on the left, low: light travels along +axis (azimuth clockwise from north)
    toward_sun = -axis
    azimuth = math.degrees(math.atan2(toward_sun[0], toward_sun[1]))
    env = replace(scene.environment, sun_elevation_deg=15.0, sun_azimuth_deg=azimuth,
                  sun_strength=4.0)
    objects = [scene.objects[0], box("near", 0.0, 1.0), box("far", 10 * half_m, 1.0),
               box("left", -(half_m + 16.0), 10.0), box("right", half_m + 16.0, 10.0)]
    scene = replace(scene, environment=env, objects=objects)
    kept = [o.name for o in objects_in_view(scene, sun_angle_deg=1.5)]
    assert kept == [objects[0].name, "near", "left"]
    high_sun = replace(scene, environment=replace(env, sun_elevation_deg=80.0))
    assert [o.name for o in objects_in_view(high_sun, sun_angle_deg=1.5)] == [objects[0].name, "near"]


def test_light_directions_point_down_from_the_sun_and_span_its_disk():
    directions = light_directions(30.0, 90.0, 15.0)          # the sun in the east
    assert np.allclose(np.linalg.norm(directions, axis=1), 1.0)
    assert (directions[:, 2] < 0).all() and (directions[:, 0] < 0).all()   # travelling west, down
    assert directions[0] == pytest.approx([-math.cos(math.radians(30)), 0.0, -0.5], abs=1e-9)
    lowest = directions[1]
    assert lowest[2] == pytest.approx(-math.sin(math.radians(22.5)))


def test_a_dataset_from_before_the_option_resumes_without_culling(tmp_path):
    config = SimulationConfig(seed=2, preset="tiny")
    assert SimulationConfig.from_dict({"seed": 2, "preset": "tiny"}).cull_out_of_view is False
    assert SimulationConfig.from_dict(config.to_dict()).cull_out_of_view is True
    out = tmp_path / "old"
    out.mkdir()
    parameters = config.to_dict()
    del parameters["cull_out_of_view"]
    (out / "dataset.json").write_text(json.dumps({"parameters": parameters}))
    with pytest.raises(InputError, match="cull_out_of_view: False vs True"):
        simulate(out, 1, config)


def test_culled_and_full_renders_have_the_same_labels(tmp_path):
    """A tiny marina frame (its many boats mostly outside the view): the same instance ids
    and labels with and without culling, and RGB within a few grey levels."""
    import cv2

    config = SimulationConfig(seed=4, preset="tiny", vessel_pool=1, altitudes_m=(60.0,),
                              scenario="marina")
    images = {}
    for cull in (True, False):
        out = tmp_path / f"cull-{cull}"
        summary = simulate(out, 1, replace(config, cull_out_of_view=cull))
        assert not summary.failed, [f.error for f in summary.failed]
        images[cull] = {sub: cv2.imread(str(out / sub / "000000.png"), cv2.IMREAD_UNCHANGED)
                        for sub in ("images", "labels", "instances")}
    assert np.array_equal(images[True]["instances"], images[False]["instances"])
    assert np.array_equal(images[True]["labels"], images[False]["labels"])
    difference = np.abs(images[True]["images"].astype(int) - images[False]["images"].astype(int))
    assert difference.mean() < 1.0
