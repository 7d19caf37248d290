"""Vessel spec, hull outline and sections."""

from harborsight.vessel.sections import SectionAssignment, SectionedOutline
from harborsight.vessel.spec import VesselSpec, load_vessel_spec, parse_vessel_spec

__all__ = [
    "SectionAssignment",
    "SectionedOutline",
    "VesselSpec",
    "load_vessel_spec",
    "parse_vessel_spec",
]
