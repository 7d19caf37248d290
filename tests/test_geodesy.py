"""Geodetic <-> ENU against pyproj's topocentric conversion (independent of pymap3d)."""

import numpy as np
import pyproj
import pytest

from harborsight.geometry.geodesy import GeoOrigin, enu_to_geodetic, geodetic_to_enu


def pyproj_enu(lat, lon, h, origin: GeoOrigin) -> np.ndarray:
    pipeline = (
        "+proj=pipeline +step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lat_0={origin.lat_deg} +lon_0={origin.lon_deg} "
        f"+h_0={origin.alt_m}"
    )
    transformer = pyproj.Transformer.from_pipeline(pipeline)
    return np.array(transformer.transform(lon, lat, h))


@pytest.mark.parametrize("lat0, lon0", [(56.15, 10.21), (-33.86, 151.21), (69.65, 18.96)])
def test_enu_matches_pyproj(lat0, lon0):
    origin = GeoOrigin(lat0, lon0, 2.5)
    rng = np.random.default_rng(3)
    for _ in range(10):
        lat = lat0 + rng.uniform(-0.003, 0.003)
        lon = lon0 + rng.uniform(-0.003, 0.003)
        h = rng.uniform(0, 150)
        ours = geodetic_to_enu(lat, lon, h, origin)
        theirs = pyproj_enu(lat, lon, h, origin)
        assert np.allclose(ours, theirs, atol=1e-6)


def test_enu_hand_value_and_round_trip():
    # one arc-second of latitude is about 30.9 m at 56 deg N (WGS84 meridian radius 6.3828e6 m)
    origin = GeoOrigin(56.0, 10.0, 0.0)
    enu = geodetic_to_enu(56.0 + 1 / 3600, 10.0, 0.0, origin)
    assert enu[1] == pytest.approx(6_382_800 * np.radians(1 / 3600), rel=2e-3)
    assert abs(enu[0]) < 1e-6
    back = enu_to_geodetic(np.array([120.0, -45.0, 80.0]), origin)
    assert np.allclose(geodetic_to_enu(*back, origin), [120.0, -45.0, 80.0], atol=1e-6)
