"""AIS (issue #29): the vessel's track and hull from its transponder. Fixtures are written by
pyais's own encoder, with NMEA 4.10 tag blocks for the receiver's time, never typed by hand."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
import shapely
from pyais.encode import encode_dict
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.telemetry.ais import read_ais_dimensions, read_ais_file, read_ais_track
from harborsight.telemetry.vessel_track import read_vessel_track
from harborsight.vessel.spec import AIS_OUTLINE_SIGMA_M, load_vessel_spec
from tests.helpers import ais_tag_block, nmea_checksum, torn_copies

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
LOGS = SAMPLES / "flight" / "logs"
START = 1_777_636_800                    # 2026-05-01T12:00:00Z
OWN, OTHER = 219000001, 219999999


def _report(k: int, heading: int = 118, **fields) -> dict:
    return {"type": 1, "mmsi": OWN, "lat": 56.1517 - 1e-5 * k, "lon": 10.2283, "heading": heading,
            "course": 117.7, "speed": 0.8, "second": (2 * k) % 60, "status": 0, **fields}


def _log(tmp_path: Path, lines: list[str], name: str = "ship.ais") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _own_log(tmp_path: Path, n: int = 10, heading: int = 118) -> Path:
    lines = []
    for k in range(n):       # received 1.4 s after each fix, another vessel in between
        lines.append(ais_tag_block(START + 2 * k + 1.4) + encode_dict(_report(k, heading))[0])
        other = {"type": 18, "mmsi": OTHER, "lat": 56.2, "lon": 10.3, "heading": 10, "second": 5}
        lines.append(ais_tag_block(START + 2 * k + 1.5) + encode_dict(other, sentence_type="VDM",
                                                             radio_channel="B")[0])
    static = {"type": 5, "mmsi": OWN, "shipname": "HARBOUR TUG", "to_bow": 20, "to_stern": 12,
              "to_port": 5, "to_starboard": 5, "ship_type": 52}
    lines += encode_dict(static, seq_id=3)
    lines.append("!AIVDM,1,1,,B,13@ndh@P080flT`P8ES4VCd1P000,0*00")           # bad checksum
    return _log(tmp_path, lines)


def test_the_own_vessel_track_is_timed_by_the_receiver_and_the_reports_second(tmp_path):
    track = read_vessel_track(_own_log(tmp_path))           # AIS by content, its AIVDO reports
    assert track.kind == "ais" and len(track) == 10
    # received at hh:mm:ss.4 +1 s; the report's second puts the fix on the even second
    assert track.utc_start == datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC)
    assert np.allclose(track.t_s, 2.0 * np.arange(10))
    # AIS positions are in 1/10000 minute: 0.19 m of latitude
    assert np.allclose(track.lat_deg, 56.1517 - 1e-5 * np.arange(10), atol=1.0 / 600000)
    assert np.all(track.heading_deg == 118.0)
    notes = " ".join(track.notes)
    assert "10 message(s) of other vessels left out" in notes and "1 unreadable" in notes


def test_positions_no_working_fix_gave_are_skipped_and_counted(tmp_path):
    """Time stamps 61 (manual input), 62 (dead reckoning) and 63 (position system
    inoperative: a transponder that lost its GPS repeats its last position) are not fixes."""
    lines = [ais_tag_block(START + 2 * k + 1.4)
             + encode_dict(_report(k, second=(2 * k) % 60 if k < 4 else 61 + k % 3))[0]
             for k in range(7)]
    track = read_ais_track(_log(tmp_path, lines))
    assert len(track) == 4 and np.allclose(track.t_s, 2.0 * np.arange(4))
    assert any("3 position report(s) not from a working position fix" in n for n in track.notes)
    frozen = [ais_tag_block(START + 2 * k + 1.4) + encode_dict(_report(k, second=63))[0] for k in range(3)]
    with pytest.raises(InputError, match="not from a working position fix"):
        read_ais_track(_log(tmp_path, frozen, "frozen.ais"))


def test_the_hull_dimensions_come_from_the_two_part_static_report(tmp_path):
    dims, _ = read_ais_dimensions(_own_log(tmp_path))
    assert (dims.to_bow, dims.to_stern, dims.to_port, dims.to_starboard) == (20, 12, 5, 5)
    assert dims.name == "HARBOUR TUG" and dims.at_least == ()


def test_a_missing_heading_is_refused_unless_the_course_is_allowed(tmp_path):
    path = _own_log(tmp_path, heading=511)
    with pytest.raises(InputError, match="true heading"):
        read_ais_track(path)
    track = read_ais_track(path, allow_cog_heading=True)
    assert np.allclose(track.heading_deg, 117.7, atol=0.05)
    assert any(note.startswith("WARNING") and "course over ground" in note for note in track.notes)


def test_a_log_without_receiver_times_is_refused_and_iso_prefixes_are_read(tmp_path):
    bare = _log(tmp_path, [encode_dict(_report(k))[0] for k in range(3)], "bare.ais")
    with pytest.raises(InputError, match="receiver times"):
        read_ais_track(bare)
    stamped = _log(tmp_path, [f"2026-05-01T12:00:{2 * k + 1:02d}.3Z " + encode_dict(_report(k))[0]
                              for k in range(3)], "stamped.ais")
    assert np.allclose(read_ais_track(stamped).t_s, [0.0, 2.0, 4.0])
    assert not any("no zone" in note for note in read_ais_track(stamped).notes)
    # a logger's time without a zone is taken as UTC, and the track says so (local time would
    # put the vessel hours off, and the reports' second of the minute cannot tell)
    zoneless = _log(tmp_path, [f"2026-05-01 12:00:{2 * k + 1:02d} " + encode_dict(_report(k))[0]
                               for k in range(3)], "zoneless.ais")
    track = read_ais_track(zoneless)
    assert track.utc_start == datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC)
    assert any("3 receiver time(s) at the start of a line carry no zone" in note for note in track.notes)


def test_the_vessel_is_chosen_by_mmsi(tmp_path):
    lines = [ais_tag_block(START + 1) + encode_dict(_report(0), sentence_type="VDM")[0],
             ais_tag_block(START + 1) + encode_dict(_report(0, mmsi=OTHER), sentence_type="VDM")[0]]
    path = _log(tmp_path, lines)
    with pytest.raises(InputError, match="give --mmsi"):
        read_ais_track(path)
    assert len(read_ais_track(path, mmsi=OTHER)) == 1
    with pytest.raises(InputError, match="no message from MMSI 123"):
        read_ais_track(path, mmsi=123)


@pytest.mark.parametrize("bow", ["pointed", "box"])
def test_vessel_from_ais_writes_a_spec_of_the_hull(tmp_path, bow):
    out = tmp_path / "vessel.yaml"
    result = CliRunner().invoke(app, ["vessel", "from-ais", str(_own_log(tmp_path)), "--out", str(out),
                                      "--bow", bow, "--sections", "12"])
    assert result.exit_code == 0, result.output
    spec = load_vessel_spec(out)
    hull = shapely.Polygon(spec.outline)
    minx, miny, maxx, maxy = hull.bounds
    assert (minx, maxx, miny, maxy) == pytest.approx((-12.0, 20.0, -5.0, 5.0))   # A, B, C, D
    # by hand: a box is 32 x 10; the pointed bow cuts two triangles of 10 x 5 m (one beam long)
    assert hull.area == pytest.approx(320.0 if bow == "box" else 320.0 - 50.0)
    assert spec.sections().n_sections == 12 and spec.name == "harbour-tug"
    assert spec.outline_sigma_m == AIS_OUTLINE_SIGMA_M and not spec.notes


def _flight_ais(tmp_path: Path) -> Path:
    """The bundled flight's ship track re-sent as AIS position reports (whole seconds, heading
    rounded to a degree as AIS does), received 0.3 s after each fix."""
    nmea = read_vessel_track(LOGS / "ship.nmea")
    lines = []
    for t, lat, lon, heading in zip(nmea.t_s, nmea.lat_deg, nmea.lon_deg, nmea.heading_deg, strict=True):
        when = nmea.utc_start.timestamp() + t
        if abs(when - round(when)) > 1e-6:
            continue                         # AIS reports whole seconds
        report = {"type": 1, "mmsi": OWN, "lat": lat, "lon": lon, "heading": round(heading),
                  "second": round(when) % 60}
        lines.append(ais_tag_block(when + 0.3) + encode_dict(report)[0])
    return _log(tmp_path, lines)


def test_an_ais_track_drives_telemetry_video_like_the_nmea_one(tmp_path):
    """The bundled flight's ship track, re-sent as its AIS reports (heading rounded to a degree
    as AIS does), gives the same frames as its NMEA within AIS's resolution."""
    ais = _flight_ais(tmp_path)
    outputs = {}
    for name, track in (("nmea", LOGS / "ship.nmea"), ("ais", ais)):
        out = tmp_path / f"{name}.jsonl"
        result = CliRunner().invoke(app, [
            "telemetry", "video", str(LOGS / "flight.SRT"), "--vessel-track", str(track),
            "--camera", "dji-mavic3", "--water-level-m", "0", "--video", str(LOGS / "flight.mp4"),
            "--video-start", "2026-05-01T12:00:00Z", "--out", str(out)])
        assert result.exit_code == 0, result.output
        outputs[name] = [json.loads(line) for line in out.read_text().splitlines()]
    both = {f["frame_index"]: f for f in outputs["nmea"]}
    matched = [(both[f["frame_index"]], f) for f in outputs["ais"] if f["frame_index"] in both]
    assert len(matched) >= 40
    for a, b in matched:
        assert abs(a["vessel"]["lat"] - b["vessel"]["lat"]) < 1.5e-6       # 0.17 m
        assert abs(a["vessel"]["heading_deg"] - b["vessel"]["heading_deg"]) <= 0.5


def test_a_torn_or_salted_ais_log_never_raises_and_keeps_what_came_before(tmp_path):
    whole = _own_log(tmp_path, n=20).read_bytes()
    complete = len(read_ais_file(tmp_path / "ship.ais").reports)
    for trial, cut, data in torn_copies(whole):
        path = tmp_path / "torn.ais"
        path.write_bytes(data)
        lines_before = whole[:cut].count(b"\n")
        try:
            ais = read_ais_file(path)
            track = read_ais_track(path, mmsi=OWN)
        except InputError as exc:               # a clear refusal, naming the file
            assert str(path) in str(exc)
            continue
        if trial % 2 == 0:      # only cut: every whole line before the cut was read
            assert len(ais.reports) >= min(complete, lines_before) - 2
            assert len(track) >= lines_before // 2 - 1


def _with_checksum(body: str) -> str:
    return f"!{body}*{nmea_checksum(body)}"


def test_a_payload_cut_inside_its_mmsi_and_a_receiver_time_at_the_end_of_time(tmp_path):
    """Found by benchmarks/fuzz_parsers.py: a payload of one character decodes with no MMSI
    (it was int(None)), and a receiver time in the last minute of the year 9999 overflowed
    while being moved to the report's second."""
    own = _own_log(tmp_path).read_text().splitlines()
    lines = [ais_tag_block(START) + _with_checksum("AIVDO,1,1,,A,1,0"),
             "9999-12-31T23:59:59Z " + encode_dict(_report(0))[0], *own]
    path = _log(tmp_path, lines, "odd.ais")
    ais = read_ais_file(path)
    assert ais.unreadable >= 2                  # the cut payload and the bad checksum
    track = read_ais_track(path, mmsi=OWN)
    assert len(track) == 11                     # the year-9999 fix kept, at a time of its own
    at = track.seconds_of(datetime.fromtimestamp(START + 5, UTC))
    assert np.isfinite(track.sample(np.array([at]))["lat_deg"]).all()


def test_an_ais_vessel_track_through_to_reports(tmp_path):
    """AIS to a report: DJI photos of the flight (tests/test_dji_photo.py), the vessel from its
    AIS reports, measured with the exact masks, against the ground truth."""
    import shutil

    from tests.test_dji_photo import _flight_photo

    indices = (10, 24, 38)                   # whole seconds: AIS reports whole seconds
    masks = tmp_path / "masks"
    masks.mkdir()
    for index in indices:
        _flight_photo(tmp_path, index)
        shutil.copy(SAMPLES / "flight" / "labels" / f"{index:06d}.png", masks / f"DJI_{index:04d}.png")
    runner = CliRunner()
    result = runner.invoke(app, ["telemetry", "photos", str(tmp_path / "photos"), "--vessel-track",
                                 str(_flight_ais(tmp_path)), "--mmsi", str(OWN),
                                 "--water-level-m", "0", "--out", str(tmp_path / "frames")])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["measure", str(tmp_path / "frames"), "--masks", str(masks),
                                 "--vessel", str(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"),
                                 "--out", str(tmp_path / "out"), "--no-tables"])
    assert result.exit_code == 0, result.output
    errors = []
    for index in indices:
        report = json.loads((tmp_path / "out" / f"DJI_{index:04d}.json").read_text())
        truth = json.loads((SAMPLES / "flight" / "frames" / f"{index:06d}.json").read_text())
        expected = {s["index"]: s["distance_m"] for s in truth["ground_truth"]["sections"]}
        errors += [abs(s["distance_m"] - expected[s["index"]]) for s in report["sections"]
                   if s["status"] == "ok" and expected.get(s["index"]) is not None]
    assert len(errors) >= 12 and np.median(errors) < 0.2
