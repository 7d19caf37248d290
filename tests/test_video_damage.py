"""A video damaged in the middle: the frames decoded from damaged data are named and not
measured, and the others keep their numbers and pictures. OpenCV's reader stopped at the
first damaged packet of an MP4 (the rest of the flight unread), and in an MPEG-TS the
decoder's concealed frames, up to 30 grey levels off, were measured as if whole."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.flight.video_decode import NOT_DECODED, read_video_frames

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
runner = CliRunner()
FRAMES, KEY_EVERY = 45, 15               # key frames at 0, 15 and 30


def _picture(k: int, size=(96, 64)) -> np.ndarray:
    picture = np.zeros((size[1], size[0], 3), np.uint8)
    picture[..., 0], picture[..., 2] = 90, 40
    picture[16:48, 4 + 2 * k:36 + 2 * k] = 200            # a block moving right
    picture[::5] += 25
    return picture


def _write(path: Path, fmt: str | None = None, codec: str = "libx264", b_frames: int = 0,
           skip: int | None = None) -> None:
    """A clip of FRAMES frames at 10 fps, a key frame every KEY_EVERY; ``skip``: a frame the
    camera never sent (its time left empty)."""
    import av

    with av.open(str(path), "w", format=fmt) as out:
        stream = out.add_stream(codec, rate=10)
        stream.width, stream.height, stream.pix_fmt = 96, 64, "yuv420p"
        stream.options = ({"g": str(KEY_EVERY), "keyint_min": str(KEY_EVERY), "bf": str(b_frames),
                           "sc_threshold": "0"} if codec == "libx264" else
                          {"x265-params": f"keyint={KEY_EVERY}:min-keyint={KEY_EVERY}:log-level=0"})
        for k in range(FRAMES):
            if k == skip:
                continue
            frame = av.VideoFrame.from_ndarray(_picture(k), format="bgr24")
            frame.pts = k
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def _decoded(path: Path) -> list[np.ndarray]:
    import av

    with av.open(str(path)) as container:
        return [f.to_ndarray(format="bgr24") for f in container.decode(video=0)]


def _packet_spans(path: Path) -> list[tuple[int, int, bool]]:
    """(byte offset, size, key) of each video packet in the file, in decoding order."""
    import av

    with av.open(str(path)) as container:
        return [(p.pos, p.size, p.is_keyframe) for p in container.demux(video=0) if p.size]


def _scramble(path: Path, start: int, size: int, seed: int = 0) -> None:
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(seed)
    for offset in range(start, start + size, 3):
        data[offset] = int(rng.integers(0, 256))
    path.write_bytes(bytes(data))


def _check(pictures, clean: list[np.ndarray], damaged: set[int]) -> None:
    assert [p.index for p in pictures] == list(range(FRAMES))
    for p in pictures:
        if p.index in damaged:
            assert p.damaged, p.index
        else:
            assert p.damaged is None, (p.index, p.damaged)
            assert np.array_equal(p.image, clean[p.index]), p.index
    assert [round(p.time_s, 6) for p in pictures if p.time_s is not None][:3] == [0.0, 0.1, 0.2]


def test_a_damaged_packet_in_an_mp4_costs_its_frames_up_to_the_next_key_frame(tmp_path):
    video = tmp_path / "flight.mp4"
    _write(video)
    clean = _decoded(video)
    assert len(clean) == FRAMES
    start, size, key = _packet_spans(video)[20]
    assert not key
    _scramble(video, start + 8, size - 12)
    pictures = list(read_video_frames(video))
    _check(pictures, clean, set(range(20, 30)))
    assert pictures[20].image is None and pictures[20].damaged == NOT_DECODED
    assert "decoded from damaged data (packet at 2.000 s" in pictures[21].damaged
    import cv2

    capture = cv2.VideoCapture(str(video))          # what `run` read before: 20 frames
    read = 0
    while capture.read()[0]:
        read += 1
    assert read == 20


def test_a_damaged_key_frame_in_an_mpeg_ts_is_concealed_and_named(tmp_path):
    """The decoder conceals the damaged key frame without an error returned or the frame
    flagged corrupt; it says so in its log, and that names the frames until the next key."""
    video = tmp_path / "flight.ts"
    _write(video, "mpegts")
    clean = _decoded(video)
    start, _, key = _packet_spans(video)[15]
    assert key
    packet_at = start // 188 * 188                  # the TS packet holding the PES start
    _scramble(video, packet_at + 120, 60, seed=1)   # within that TS packet's payload
    pictures = list(read_video_frames(video))
    concealed = [p.index for p in pictures if p.damaged]
    assert concealed and concealed == list(range(concealed[0], 30))
    assert concealed[0] <= 16
    _check(pictures, clean, set(concealed))
    differs = [p.index for p in pictures if p.damaged and p.image is not None
               and np.abs(p.image.astype(int) - clean[p.index]).mean() > 1.0]
    assert differs                                   # what was measured before


def test_errors_about_side_data_leave_the_picture_whole():
    """Drones write their own records into SEI messages; FFmpeg logs an error for one it
    cannot parse and decodes the picture on: not damage."""
    from harborsight.flight.video_decode import _about_side_data

    assert _about_side_data("SEI type 5 size 40 truncated at 16")
    assert not _about_side_data("error while decoding MB 0 0, bytestream 319")
    assert not _about_side_data("concealing 120 DC, 120 AC, 120 MV errors in P frame")


def _run(tmp_path: Path, video: Path, model: Path) -> tuple[dict, Path]:
    """``run`` on ``video`` with a metadata line per frame (the bundled flight's first pose,
    its camera shrunk to the clip); run.json and the output folder."""
    record = json.loads((SAMPLES / "flight" / "frames" / "000000.json").read_text())
    record["camera"].update(width=96, height=64, fx=60.0, fy=60.0, cx=47.5, cy=31.5)
    for key in ("image", "ground_truth", "simulation", "vessel_spec"):
        record.pop(key, None)
    (tmp_path / "flight.jsonl").write_text("".join(
        json.dumps({**record, "frame_index": k}) + "\n" for k in range(FRAMES)))
    vessel = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(video), "--metadata", str(tmp_path / "flight.jsonl"),
                                 "--model", str(model), "--vessel", str(vessel),
                                 "--out", str(out), "--no-overlays"],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    return json.loads((out / "run.json").read_text()), out


@pytest.mark.parametrize("damaged_packet", [20, 0])
def test_run_skips_the_damaged_frames_of_a_video_and_measures_the_rest(tmp_path, untrained_model,
                                                                       damaged_packet):
    """A damaged P frame (20) or the first key frame (0): the frames from it to the next key
    frame are skipped with the reason, the rest measured, and every frame keeps its place in
    the annotated video (a first frame without a picture too: the video's size comes from
    the container)."""
    video = tmp_path / "flight.mp4"
    _write(video)
    start, size, _ = _packet_spans(video)[damaged_packet]
    _scramble(video, start + 8, size - 12)
    summary, out = _run(tmp_path, video, untrained_model)
    skipped = {item["frame"]: item["error"] for item in summary["skipped_frames"]}
    first = damaged_packet
    last = (damaged_packet // KEY_EVERY + 1) * KEY_EVERY
    assert sorted(skipped) == list(range(first, last))
    assert "damaged" in skipped[first + 5] and f"flight.jsonl:{first + 6}" in skipped[first + 5]
    assert summary["measured"] == FRAMES - (last - first)
    assert len(_decoded(out / "annotated.mp4")) == FRAMES


@pytest.mark.parametrize("fmt", ["mp4", "mpegts"])
def test_a_whole_video_has_no_damaged_frame(tmp_path, fmt):
    video = tmp_path / f"clean.{fmt}"
    _write(video, None if fmt == "mp4" else fmt)
    pictures = list(read_video_frames(video))
    assert len(pictures) == FRAMES and not any(p.damaged for p in pictures)


def test_the_live_reader_passes_damaged_frames_on_named_and_keeps_the_stream(tmp_path,
                                                                            monkeypatch):
    """A packet that failed to decode ended the live reader's stream ("stopped sending"),
    which it then opened again; the frames concealed after it were measured. Now the stream
    goes on and those frames carry the reason (the live aid does not measure them)."""
    import threading

    import av

    from harborsight.live import video_in
    from harborsight.live.stream import LatestFrame

    video = tmp_path / "link.ts"
    _write(video, "mpegts")
    start, _, _ = _packet_spans(video)[15]
    _scramble(video, start // 188 * 188 + 120, 60, seed=1)
    opened, frames, warnings = [], [], []
    stop = threading.Event()

    def arrived(frame, now_s):
        frames.append(frame)
        if len(frames) == FRAMES:
            stop.set()

    def open_once(*args):
        opened.append(1)
        return av.open(str(video))

    monkeypatch.setattr(video_in, "_open", open_once)
    video_in.read_stream("udp://127.0.0.1:1", LatestFrame(), stop, on_arrival=arrived,
                         warn=warnings.append)
    assert len(opened) == 1
    named = [f.index for f in frames if f.error]
    assert named and named[-1] == 29 and all("damaged" in f.error for f in frames if f.error)
    assert any("decoded from damaged data, not measured" in w for w in warnings)


def test_with_b_frames_the_damaged_group_s_last_pictures_are_named_too():
    """The decoder outputs the last frames of a damaged group after the next key packet (the
    B-frames' reorder delay): damage ends only when that key packet's own picture comes out.
    The first version ended it at the packet and passed those frames on as whole."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        video = Path(folder) / "bframes.mp4"
        _write(video, b_frames=2)
        clean = _decoded(video)
        start, size, key = _packet_spans(video)[20]
        assert not key
        _scramble(video, start + 8, size - 12)
        pictures = list(read_video_frames(video))
    assert [p.index for p in pictures] == list(range(FRAMES))
    wrong = [p.index for p in pictures if p.image is None
             or np.abs(p.image.astype(int) - clean[p.index]).mean() > 1.0]
    named = [p.index for p in pictures if p.damaged]
    assert wrong and set(wrong) <= set(named)
    assert max(named) < 2 * KEY_EVERY and not any(p.damaged for p in pictures[2 * KEY_EVERY:])


def test_a_transport_stream_packet_lost_on_the_way_is_named(tmp_path):
    """188 bytes cut out of an MPEG-TS (a packet lost on a UDP link): the demuxer flags the
    video packet corrupt, whether or not the decoder complains."""
    video = tmp_path / "link.ts"
    _write(video, "mpegts")
    start, size, key = _packet_spans(video)[KEY_EVERY]
    assert key and size > 188
    data = video.read_bytes()
    cut = (start // 188 + 1) * 188                      # the key frame's second TS packet
    video.write_bytes(data[:cut] + data[cut + 188:])
    pictures = list(read_video_frames(video))
    named = [p.index for p in pictures if p.damaged]
    assert KEY_EVERY in named and set(range(KEY_EVERY, 2 * KEY_EVERY)) <= set(named)
    assert not any(p.damaged for p in pictures[2 * KEY_EVERY:])
    assert any("container flagged" in p.damaged for p in pictures if p.damaged)


def test_a_gap_in_a_steady_video_s_times_names_the_frames_up_to_the_next_key(tmp_path):
    """A frame whose packet is gone leaves only a longer step between the times around it;
    the frames after it may predict from it. Numbering stays by rank (as `telemetry video`
    pairs its metadata), so nothing is renumbered."""
    video = tmp_path / "skipped.mp4"
    _write(video, skip=20)
    pictures = list(read_video_frames(video))
    assert [p.index for p in pictures] == list(range(FRAMES - 1))
    assert pictures[20].time_s == pytest.approx(2.1)      # the frame shown at 2.1 s
    next_key = next(k for k, (_, _, key) in enumerate(_packet_spans(video)) if key and k > 20)
    assert [p.index for p in pictures if p.damaged] == list(range(20, next_key))


def test_a_video_whose_decoder_hides_damage_is_said_once(tmp_path):
    from harborsight.flight.video_decode import damage_detection_note

    hevc, h264 = tmp_path / "drone.mp4", tmp_path / "other.mp4"
    _write(hevc, codec="libx265")
    _write(h264)
    assert "HEVC (H.265)" in damage_detection_note(hevc)
    assert damage_detection_note(h264) is None



def test_the_damage_tracker_s_rules_one_by_one():
    """Packets in decoding order, frames as the decoder gives them (times in frame steps)."""
    from harborsight.flight.video_decode import DamageTracker

    tracker = DamageTracker()
    tracker.packet(False, "bad", 4)                    # a P frame's packet fails
    assert tracker.frame(3, False, False, False) == "bad"
    tracker.packet(True, None, 8)                      # the next key packet, clean
    assert tracker.frame(6, False, False, False) == "bad"   # B-frames output after it
    assert tracker.frame(8, True, True, False) is None       # its own I picture: whole
    assert tracker.frame(7, False, False, False) == "bad"    # a leading picture from before
    assert tracker.frame(9, False, False, False) is None
    assert tracker.frame(2, False, False, False) is None     # times stepping back later
                                                              # (an encoder restarted) are not
    # an intra-refresh stream: recovery points are key packets of P pictures
    tracker.packet(False, "lost", 20)
    tracker.packet(True, None, 30)
    assert tracker.frame(30, False, False, False) == "lost"  # the first: still refreshing
    tracker.packet(True, None, 45)
    assert tracker.frame(45, False, False, False) is None    # the second: refreshed
    # a stream without times (raw H.264 over UDP)
    tracker.packet(False, "bad", None)
    tracker.packet(True, None, None)
    assert tracker.frame(None, True, True, False) is None
    assert tracker.frame(None, False, False, True) == "the decoder flagged the frame corrupt"
    # an untimed stream with B-frames: a frame of the damaged group output after the key
    # packet does not take the key's slot (before, the damage ran on a whole group more)
    tracker = DamageTracker()
    tracker.packet(False, "bad", None)
    tracker.packet(True, None, None)
    assert tracker.frame(None, False, False, False) == "bad"
    assert tracker.frame(None, True, True, False) is None
    # damage seen in a picture output after the next key packet was decoded (B-frames): that
    # key's own picture still ends it (before, the damage ran on to the key after it)
    tracker = DamageTracker()
    tracker.packet(False, None, 60)
    tracker.packet(True, None, 64)
    tracker.seen("changed suddenly")
    assert tracker.frame(63, False, False, False) == "changed suddenly"
    assert tracker.frame(64, True, True, False) is None
    tracker.packet(False, None, 65)
    tracker.seen("changed suddenly")                   # no key pending: from this packet on
    tracker.packet(True, None, 70)
    assert tracker.frame(69, False, False, False) == "changed suddenly"
    assert tracker.frame(70, True, True, False) is None


def test_a_video_trimmed_without_re_encoding_starts_at_its_first_shown_frame(tmp_path):
    """A clip cut with `-c copy` keeps the packets before its edit list's start, flagged
    discard: decoded as references, never shown. They were counted as frames: 10 frames
    "not decoded" ahead of the first shown one, the rest of its group named damaged, and the
    times offset by 0.4 s."""
    import av

    source, trimmed = tmp_path / "source.mp4", tmp_path / "trimmed.mp4"
    _write(source, b_frames=2)
    with av.open(str(source)) as given, av.open(str(trimmed), "w") as out:
        stream = given.streams.video[0]
        copy = out.add_stream_from_template(stream)
        shift = round(0.4 / float(stream.time_base))      # 4 frames at 10 fps before the start
        for packet in given.demux(stream):
            if packet.dts is None:
                continue
            packet.pts -= shift
            packet.dts -= shift
            packet.stream = copy
            out.mux(packet)
    pictures = list(read_video_frames(trimmed))
    import cv2

    capture, shown = cv2.VideoCapture(str(trimmed)), 0
    while capture.read()[0]:
        shown += 1
    assert len(pictures) == shown == FRAMES - 4
    assert not any(p.damaged for p in pictures) and pictures[0].time_s == 0.0
