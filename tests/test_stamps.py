"""Frame times coarser than the frames (harborsight.flight.stamps), by hand."""

import math

import pytest

from harborsight.flight.stamps import StampResolution


def test_the_step_and_the_note_by_hand():
    stamps = StampResolution()
    assert stamps.observe(0, 10.0) == (0.0, None)
    assert stamps.observe(1, 10.5) == (0.0, None)          # different times: nothing shared
    sigma, note = stamps.observe(2, 10.5)                   # shared: the step seen is 0.5 s
    assert sigma == pytest.approx(0.5 / math.sqrt(12.0)) and "frame 2" in note
    assert stamps.observe(3, 12.0) == (pytest.approx(0.5 / math.sqrt(12.0)), None)   # once
    assert stamps.observe(4, 11.0)[1] is None and stamps.step_s == 0.5   # behind: no step


def test_a_clock_to_the_second_before_any_step_is_seen_and_after_a_restart():
    stamps = StampResolution()
    stamps.observe(0, 3.0)
    assert stamps.observe(1, 3.0)[0] == pytest.approx(1.0 / math.sqrt(12.0))   # 1 s taken
    assert stamps.observe(2, 900.0)[0] == pytest.approx(1.0 / math.sqrt(12.0))   # a glitch
    stamps.restart()                                        # ahead, taken as wrong
    assert stamps.observe(3, 4.0)[0] == pytest.approx(1.0 / math.sqrt(12.0))
    stamps.observe(4, 4.25)
    assert stamps.step_s == 0.25                            # the frames' clock again
