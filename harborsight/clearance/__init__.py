"""Contours, section bands and distances -> ``harborsight.report/1`` (numpy + OpenCV only)."""

from harborsight.clearance.measure import (
    METHODS,
    ClearanceSettings,
    check_label_mask,
    measure_clearance,
    measure_frame,
)
from harborsight.clearance.report import ClearanceReport, SectionClearance

__all__ = [
    "METHODS",
    "ClearanceReport",
    "ClearanceSettings",
    "SectionClearance",
    "check_label_mask",
    "measure_clearance",
    "measure_frame",
]
