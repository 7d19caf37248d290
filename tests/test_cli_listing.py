"""Long lists of per-frame messages on the terminal: each kind once, with a count, the frames
and the range of each quantity of the rest (cli/listing.py); run.json keeps every one."""

from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.cli.listing import frame_ranges, grouped_lines, message_kind, name_ranges


def test_a_kind_is_the_message_without_its_source_and_quantities():
    assert message_kind("a/000019.json: carried 31 s, 2.5 m", "a/000019.json") == "carried # s, # m"
    assert message_kind("000019: a/000019.json: carried 31 s", "000019") == "carried # s"
    assert message_kind("x 0.42 and 16px and 40 %") == "x # and #px and # %"
    # numbers that name the problem stay: classes, error numbers, file names, counts
    for text in ("unknown class values [3]", "[Errno 28] No space left", "tug7.yaml not found",
                 "3 of 12 sections"):
        assert message_kind(text) == text
    assert message_kind("values [3]") != message_kind("values [128]")


def test_frames_and_names_read_as_ranges():
    assert frame_ranges([7, 8, 9, 12, 15, 16, 15]) == "7-9, 12, 15-16"
    assert frame_ranges(range(0, 40, 2), shown=3) == "0, 2, 4, ..."
    assert frame_ranges([]) == ""
    assert name_ranges(["DJI_0007", "DJI_0008", "DJI_0009", "DJI_0012", "harbor", "h3"]) == (
        "DJI_0007-0009, DJI_0012, harbor, h3")


def test_each_kind_shows_three_then_counts_the_rest_with_frames_and_ranges():
    items = [(k, f"f/{k:06d}.json: carried {30 + k} s, {k / 2:.1f} m off", f"f/{k:06d}.json")
             for k in range(4, 48) if k != 14]
    items.insert(10, (14, "f/000014.json: unknown class values [3]", "f/000014.json"))
    items += [(k, f"f/{k:06d}.json: unknown class values [128]", f"f/{k:06d}.json") for k in (20, 21)]
    lines = grouped_lines(items)
    assert lines == ["  f/000004.json: carried 34 s, 2.0 m off", "  f/000005.json: carried 35 s, 2.5 m off",
                     "  f/000006.json: carried 36 s, 3.0 m off",
                     "  ... and 40 more like the last (frames 7-13, 15-47; 37 to 77 s, 3.5 to 23.5 m)",
                     "  f/000014.json: unknown class values [3]",
                     "  f/000020.json: unknown class values [128]",
                     "  f/000021.json: unknown class values [128]"]
    assert grouped_lines([(None, "one", None)] * 5, shown=1) == ["  one", "  ... and 4 more like the last"]
    named = grouped_lines([(f"DJI_{k:04d}", f"DJI_{k:04d}: photos/DJI_{k:04d}.json: no pose", f"DJI_{k:04d}")
                           for k in range(10)])
    assert named[-1] == "  ... and 7 more like the last (DJI_0003-0009)"


def test_run_lists_a_flood_of_one_kind_once(tmp_path):
    """44 frames of the bundled flight whose vessel report is 21-44 s old, and no pose
    refinement to carry them: the terminal shows three and counts 41 more; run.json has 44."""
    from tests.test_pose_carry import _class_b_flight, run_with_masks

    flight = _class_b_flight(tmp_path, placed_frames=4)
    result, record = run_with_masks(flight, tmp_path / "out", "--no-refine-pose")
    text = " ".join(result.output.split())
    assert "44 frame(s) skipped" in text and "... and 41 more like the last (frames 7-47; " in text
    assert text.count("vessel.dead_reckoned_s") == 3
    assert len(record["skipped_frames"]) == 44


def test_measure_names_every_frame_it_skipped(tmp_path):
    """`measure` writes no record of what it skipped: the names of the frames counted, every
    one, are on the terminal."""
    from tests.test_pose_carry import VESSEL, _class_b_flight

    flight = _class_b_flight(tmp_path, placed_frames=4)
    result = CliRunner().invoke(app, ["measure", str(flight), "--masks", str(flight / "labels"),
                                      "--vessel", str(VESSEL), "--out", str(tmp_path / "out"),
                                      "--no-tables", "--no-refine-pose"])
    text = " ".join(result.output.split())
    assert "44 frame(s) skipped" in text and "... and 41 more like the last (000007-000047; " in text
