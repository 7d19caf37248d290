"""Long lists of per-frame messages on the terminal: each kind once, with a count and the
frames of the rest (cli/listing.py); run.json keeps every one."""



from harborsight.cli.listing import frame_ranges, grouped_lines, message_kind


def test_a_kind_is_the_message_without_its_source_and_numbers():
    assert message_kind("a/000019.json: carried 31 s, 2.5 m", "a/000019.json") == "carried # s, # m"
    assert message_kind("a/000019.json: carried 31 s", None) == "a/#.json: carried # s"
    assert message_kind("x -1.5e3") == "x #e#"


def test_frames_read_as_ranges():
    assert frame_ranges([7, 8, 9, 12, 15, 16, 15]) == "7-9, 12, 15-16"
    assert frame_ranges(range(0, 40, 2), shown=3) == "0, 2, 4, ..."
    assert frame_ranges([]) == ""


def test_each_kind_shows_three_then_counts_the_rest_in_first_come_order():
    items = [(k, f"f/{k:06d}.json: carried {30 + k} s", f"f/{k:06d}.json") for k in range(4, 48)
             if k != 14]
    items.insert(10, (14, "f/000014.json: unreadable image", "f/000014.json"))
    lines = grouped_lines(items)
    assert lines == ["  f/000004.json: carried 34 s", "  f/000005.json: carried 35 s",
                     "  f/000006.json: carried 36 s",
                     "  ... and 40 more like the last (frames 7-13, 15-47)",
                     "  f/000014.json: unreadable image"]
    assert grouped_lines([(None, "one", None)] * 5, shown=1) == ["  one", "  ... and 4 more like the last"]


def test_run_lists_a_flood_of_one_kind_once(tmp_path):
    """44 frames of the bundled flight whose vessel report is 30-44 s old, and no pose
    refinement to carry them: the terminal shows three and counts 41 more; run.json has 44."""
    from tests.test_pose_carry import _class_b_flight, run_with_masks

    flight = _class_b_flight(tmp_path, placed_frames=4)
    result, record = run_with_masks(flight, tmp_path / "out", "--no-refine-pose")
    text = result.output
    assert "44 frame(s) skipped" in text and "... and 41 more like the last (frames 7-47)" in text
    assert text.count("vessel.dead_reckoned_s") == 3
    assert len(record["skipped_frames"]) == 44
