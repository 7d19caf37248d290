"""The sun's direction and the vessel's shadow on the water (harborsight.geometry.sun),
against hand calculations: the solstice noon elevation at Greenwich, and a box's shadow area
measured with shapely."""

import json
import math
from datetime import UTC, datetime

import numpy as np
import pytest
from shapely.geometry import Polygon

from harborsight.frame import FrameGeometry, load_frame_metadata
from harborsight.geometry.sun import shadow_on_water, sun_position_deg, sun_ray_enu
from tests.test_inputs import SAMPLES

GREENWICH = (51.4769, -0.0005)


def test_noon_at_the_solstice_matches_a_hand_calculation():
    """On 2026-06-21 at 12:02 UTC the sun crosses Greenwich's meridian (the equation of time
    is -1.7 min) at 90 - 51.4769 + 23.44 = 61.96 degrees, due south; six hours later it is
    low in the west-north-west."""
    elevation, azimuth = sun_position_deg(*GREENWICH, datetime(2026, 6, 21, 12, 2, tzinfo=UTC))
    assert elevation == pytest.approx(61.96, abs=0.1)
    assert azimuth == pytest.approx(180.0, abs=1.0)
    evening_el, evening_az = sun_position_deg(*GREENWICH, datetime(2026, 6, 21, 18, 2,
                                                                  tzinfo=UTC))
    assert 10.0 < evening_el < 25.0 and 270.0 < evening_az < 300.0
    with pytest.raises(ValueError, match="UTC offset"):
        sun_position_deg(*GREENWICH, datetime(2026, 6, 21, 12, 2))


def test_a_box_casts_its_height_over_tan_elevation():
    """A 10 x 4 m box 2 m high, the sun at 45 degrees in the west: the shadow reaches 2 m east
    of it, footprint included 12 x 4 m (shapely's area); the light travels down and east."""
    ray = sun_ray_enu(45.0, 270.0)
    np.testing.assert_allclose(ray, [math.sqrt(0.5), 0.0, -math.sqrt(0.5)], atol=1e-12)
    corners = np.array([[x, y] for x in (-5.0, 5.0) for y in (-2.0, 2.0)])
    body = np.vstack((np.column_stack((corners, np.zeros(4))), np.column_stack((corners, np.full(4, 2.0)))))
    shadow = Polygon(shadow_on_water(body, ray))
    assert shadow.area == pytest.approx(48.0)
    assert shadow.bounds == pytest.approx((-5.0, -2.0, 7.0, 2.0))
    assert sun_ray_enu(4.9, 270.0) is None


def test_a_frame_gives_the_sun_by_its_block_or_by_its_time(tmp_path):
    """The ``sun`` block wins; without it the time and place give it (a time without a UTC
    offset gives none); the block is written back by ``to_dict``."""
    source = SAMPLES / "frames" / "000000.json"
    data = json.loads(source.read_text())
    data.pop("sun", None)
    data.pop("simulation", None)        # a frame of a real flight: no render's sun
    data["uav"].update(lat=GREENWICH[0], lon=GREENWICH[1])
    data["vessel"].update(lat=GREENWICH[0], lon=GREENWICH[1])
    path = tmp_path / "frame.json"

    def geometry_of(**changes) -> FrameGeometry:
        path.write_text(json.dumps({**data, **changes}))
        return FrameGeometry.from_metadata(load_frame_metadata(path))

    by_time = geometry_of(timestamp="2026-06-21T12:02:00Z").sun_ray_enu()
    np.testing.assert_allclose(by_time, sun_ray_enu(61.96, 180.0), atol=2e-3)
    assert geometry_of(timestamp="2026-06-21T12:02:00").sun_ray_enu() is None
    block = {"elevation_deg": 30.0, "azimuth_deg": 90.0}
    np.testing.assert_allclose(geometry_of(timestamp="2026-06-21T12:02:00Z", sun=block).sun_ray_enu(),
                               sun_ray_enu(30.0, 90.0))
    path.write_text(json.dumps({**data, "sun": block}))
    assert load_frame_metadata(path).to_dict()["sun"] == block


def test_a_rendered_scene_writes_its_sun_into_the_frame():
    """The simulator's frames carry the sun it lit the scene with (``sun`` block), so that
    the vessel's shadow can be predicted on its own renders."""
    from harborsight.geometry.camera import CameraIntrinsics
    from harborsight.sim.layout import sample_harbour_scene
    from harborsight.vessel.spec import load_vessel_spec

    vessel = load_vessel_spec(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml")
    intrinsics = CameraIntrinsics(640, 360, 450.0, 450.0, 319.5, 179.5)
    scene = sample_harbour_scene(vessel, "harbour-tug", np.random.default_rng(5), altitude_m=60.0,
                                 intrinsics=intrinsics)
    sun = scene.metadata("x.png").to_dict()["sun"]
    assert sun == {"elevation_deg": scene.environment.sun_elevation_deg,
                   "azimuth_deg": scene.environment.sun_azimuth_deg}
    np.testing.assert_allclose(scene.geometry().sun_ray_enu(),
                               sun_ray_enu(sun["elevation_deg"], sun["azimuth_deg"]))


def test_a_simulator_frame_without_a_sun_block_uses_the_sun_it_was_rendered_with():
    """Frames the simulator wrote before the ``sun`` block (the bundled flight among them)
    carry their render's sun in ``simulation.environment``: that, not their synthetic time."""
    source = SAMPLES / "flight" / "frames" / "000000.json"
    data = json.loads(source.read_text())
    env = data["simulation"]["environment"]
    assert "sun" not in data and data["timestamp"]
    geometry = FrameGeometry.from_metadata(load_frame_metadata(source))
    np.testing.assert_allclose(geometry.sun_ray_enu(),
                               sun_ray_enu(env["sun_elevation_deg"], env["sun_azimuth_deg"]))
