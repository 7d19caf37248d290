"""Every JSON harborsight writes is strict JSON: a non-finite number becomes null (issue #30:
barrel distortion put bare NaN into out-of-view sections' hull_px)."""

import json

import numpy as np

from harborsight.clearance.report import ClearanceReport, SectionClearance
from harborsight.files import finite_or_none, strict_json


def strict_loads(text: str):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def test_non_finite_numbers_become_null_at_any_depth():
    value = {"a": float("nan"), "b": [1.5, float("inf"), {"c": (float("-inf"), 2)}],
             "d": np.float32("nan"), "e": np.array([1.0, np.nan]), "f": "NaN", "g": None}
    parsed = strict_loads(strict_json(value))
    assert parsed == {"a": None, "b": [1.5, None, {"c": [None, 2]}], "d": None, "e": [1.0, None],
                      "f": "NaN", "g": None}
    assert finite_or_none(3) == 3 and finite_or_none(True) is True


def test_a_report_with_an_unprojectable_section_end_is_strict_json(tmp_path):
    sections = [
        SectionClearance(0, "ok", [[10.0, 20.0], [30.0, 40.0]], 1.0, distance_m=3.2, distance_px=60.0),
        SectionClearance(1, "out_of_view", [[float("nan"), float("nan")], [5e5, -2e5]], 0.0),
    ]
    report = ClearanceReport("f.png", None, 50.0, 0.04, "ground_plane", sections)
    path = tmp_path / "f.json"
    report.write(path)
    text = path.read_text()
    assert "NaN" not in text
    doc = strict_loads(text)
    assert doc["sections"][1]["hull_px"][0] == [None, None]
    assert doc["sections"][1]["hull_px"][1] == [5e5, -2e5]
    assert doc["min_distance_m"] == 3.2

