"""Magnetic declination from the World Magnetic Model (WMM), through pygeomag.

A magnetic heading becomes true by adding the declination D (east positive) and, for a ship's
compass, the deviation: ``true = magnetic + deviation + D``. An NMEA ``HDG`` sentence may carry
the variation (= D) itself; ``HDM`` and a bare ``HDG`` do not, and then D is computed here.

The WMM is a degree-12 spherical-harmonic model issued for five-year epochs (WMM-2010 to
WMM-2025, valid 2010.0 to 2030.0); the model of the date's epoch is used, and a date outside
them is refused rather than extrapolated. Its stated accuracy is about 0.3-0.5 deg of D at mid
latitudes; local anomalies (steel quays and the ship itself) are not in it, which is what a
ship's deviation card is for.
"""

from __future__ import annotations

from datetime import UTC, datetime
from functools import lru_cache

#: The epochs pygeomag ships: (first decimal year each is valid for, coefficient file name).
WMM_EPOCHS = ((2010, "2010"), (2015, "2015v2"), (2020, "2020"), (2025, "2025"))
WMM_END_YEAR = 2030.0


def decimal_year(when: datetime) -> float:
    """UTC time as a decimal year (2026.0 = 1 Jan 2026 00:00 UTC)."""
    when = when.astimezone(UTC) if when.tzinfo else when.replace(tzinfo=UTC)
    start = datetime(when.year, 1, 1, tzinfo=UTC)
    end = datetime(when.year + 1, 1, 1, tzinfo=UTC)
    return when.year + (when - start).total_seconds() / (end - start).total_seconds()


@lru_cache(maxsize=8)
def _model(epoch_name: str):
    from pygeomag import GeoMag

    return GeoMag(coefficients_file=f"wmm/WMM_{epoch_name}.COF")


def wmm_model_name(year: float) -> str:
    """The WMM epoch that covers a decimal year; ValueError outside 2010.0-2030.0."""
    if not 2010.0 <= year < WMM_END_YEAR:
        raise ValueError(f"no World Magnetic Model covers {year:.2f} (WMM-2010 to WMM-2025 "
                         f"cover 2010.0-{WMM_END_YEAR:.1f})")
    name = [n for start, n in WMM_EPOCHS if year >= start][-1]
    return f"WMM-{name}"


def magnetic_declination_deg(lat_deg: float, lon_deg: float, when: datetime,
                             alt_m: float = 0.0) -> float:
    """Declination D in degrees, east positive, at a WGS-84 position and UTC time."""
    year = decimal_year(when)
    name = wmm_model_name(year)
    # Positions are rounded to 0.01 deg (about 1 km) for the cache: D changes by well under
    # 0.01 deg over that distance outside polar regions.
    return _declination_cached(round(lat_deg, 2), round(lon_deg, 2), round(year, 3),
                               round(alt_m, -1), name.removeprefix("WMM-"))


@lru_cache(maxsize=4096)
def _declination_cached(lat_deg: float, lon_deg: float, year: float, alt_m: float,
                        epoch_name: str) -> float:
    result = _model(epoch_name).calculate(glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0,
                                          time=year)
    return float(result.d)
