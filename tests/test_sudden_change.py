"""Damage a decoder does not report (FFmpeg's HEVC and VP9 decoders say nothing of scrambled
data), found in the pictures: a block that changes suddenly against the frame before and is
not explained by motion. Drone-like scenes drift, turn, brighten and have boats crossing them
fast without a frame named; garbage blocks are named, and in an HEVC clip the frames from
a scrambled packet to the next key frame are."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from harborsight.flight.sudden_change import SuddenChange
from harborsight.flight.video_decode import damage_detection_note, read_video_frames

WIDTH, HEIGHT = 320, 180
SHARED_PHOTOS = (Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
                 / "aerial-maritime-drone" / "photos")


def _scene(seed: int = 3) -> np.ndarray:
    """A large grey scene: water-like smooth shading, a textured shore and pale docks."""
    rng = np.random.default_rng(seed)
    scene = np.zeros((600, 900), np.float32)
    for sigma, amplitude in ((40, 40), (8, 15), (1.5, 8)):
        scene += amplitude * cv2.GaussianBlur(rng.normal(0, 1, scene.shape).astype(np.float32),
                                              (0, 0), sigma) * sigma / 2
    shore = cv2.GaussianBlur(rng.normal(0, 1, (600, 400)).astype(np.float32), (0, 0), 1.0)
    scene[:, 500:] += 60 + 40 * shore                                               # the shore
    for top in range(100, 520, 90):
        scene[top:top + 12, 380:520] = 200                                          # docks
    return np.clip(scene + 90, 0, 255)


def _frames(n: int, *, step_px=(0.6, 0.3), turn_deg=0.05, gain_at=None, boat_px=0.0,
            seed: int = 3) -> list[np.ndarray]:
    """A drone's reduced grey frames drifting over the scene, with noise; ``gain_at``: the
    frame from which the exposure is 20 % brighter; ``boat_px``: a boat crossing that fast."""
    scene, rng = _scene(seed), np.random.default_rng(seed + 1)
    frames = []
    for k in range(n):
        centre = (450 + step_px[0] * k, 300 + step_px[1] * k)
        matrix = cv2.getRotationMatrix2D(centre, turn_deg * k, 1.0)
        matrix[:, 2] += (WIDTH / 2 - centre[0], HEIGHT / 2 - centre[1])
        frame = cv2.warpAffine(scene, matrix, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR)
        if boat_px:
            x = int(10 + boat_px * k) % (WIDTH - 40)
            frame[80:100, x:x + 30] = 230
            frame[84:96, x + 6:x + 24] = 120
        if gain_at is not None and k >= gain_at:
            frame = frame * 1.2
        frames.append(np.clip(frame + rng.normal(0, 1.5, frame.shape), 0, 255).astype(np.float32))
    return frames


def _suspects(frames: list[np.ndarray]) -> list[int]:
    check = SuddenChange()
    return [k for k, frame in enumerate(frames) if check.check(frame) is not None]


@pytest.mark.parametrize("kind", ["drift", "pan", "exposure", "fast boat"])
def test_a_whole_drone_scene_is_never_suspect(kind):
    options = {"drift": {}, "pan": {"step_px": (3.0, 1.0), "turn_deg": 0.3},
               "exposure": {"gain_at": 20}, "fast boat": {"boat_px": 7.0}}[kind]
    assert _suspects(_frames(40, **options)) == []


def test_blocks_of_garbage_are_suspect_and_the_next_frame_starts_afresh():
    frames = _frames(30)
    rng = np.random.default_rng(9)
    frames[20][64:96, 128:224] = rng.integers(0, 256, (32, 96)).astype(np.float32)
    check = SuddenChange()
    reasons = [check.check(frame) for frame in frames]
    assert [k for k, reason in enumerate(reasons) if reason] == [20]
    assert "changed suddenly" in reasons[20] and "not explained by motion" in reasons[20]
    # the frame after is not compared with the suspect one (which the caller marks damaged)
    assert reasons[21] is None


def test_a_block_shifted_by_wrong_motion_far_beyond_the_scene_s_is_suspect():
    frames = _frames(30)
    frames[20][40:104, 40:104] = frames[20][40:104, 160:224].copy()     # 120 px off
    assert _suspects(frames) == [20]


def _encode(path: Path, codec: str, options: dict, pictures, pixel_format: str) -> None:
    """A 25 fps clip of ``pictures`` (arrays in ``pixel_format``), frame k at time k."""
    import av

    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=25)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.options = options
        for k, picture in enumerate(pictures):
            frame = av.VideoFrame.from_ndarray(picture.astype(np.uint8), format=pixel_format)
            frame.pts = k
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def _write_hevc(path: Path, n: int = 40) -> None:
    """A drone drifting over a real lake-shore photo (320x180 at 25 fps, a key frame every
    20, no B-frames), with sensor noise."""
    photo = cv2.imread(str(SHARED_PHOTOS / "DJI_0262.jpg"))
    photo = cv2.resize(photo, (1024, 768), interpolation=cv2.INTER_AREA)
    rng = np.random.default_rng(1)

    def pictures():
        for k in range(n):
            centre = (512 + 0.8 * k, 384 + 0.4 * k)
            matrix = cv2.getRotationMatrix2D(centre, 0.05 * k, 0.5)
            matrix[:, 2] += (WIDTH / 2 - centre[0], HEIGHT / 2 - centre[1])
            picture = cv2.warpAffine(photo, matrix, (WIDTH, HEIGHT))
            yield np.clip(picture + rng.normal(0, 1.5, picture.shape), 0, 255)

    _encode(path, "libx265", {"x265-params": "keyint=20:min-keyint=20:bframes=0:log-level=0",
                              "crf": "26"}, pictures(), "bgr24")


def test_an_hevc_frame_decoded_from_scrambled_data_is_named_up_to_the_next_key(tmp_path):
    """FFmpeg's HEVC decoder reports nothing for it: before, all 40 frames passed whole,
    frames 7-19 with more than 1 % of their pixels over 30 grey levels off. (Most damage of
    this clip is subtler and still passes: docs/results.md.)"""
    import av

    video = tmp_path / "drone.mp4"
    _write_hevc(video)
    clean = list(read_video_frames(video))
    assert not [p.index for p in clean if p.damaged]
    with av.open(str(video)) as container:
        spans = [(p.pos, p.size, p.is_keyframe) for p in container.demux(video=0) if p.size]
    start, size, key = spans[7]
    assert not key
    data = bytearray(video.read_bytes())
    rng = np.random.default_rng(3)
    for offset in range(start + size // 4, start + size * 9 // 10, 3):
        data[offset] = int(rng.integers(1, 256))
    video.write_bytes(bytes(data))
    pictures = list(read_video_frames(video))
    assert [p.index for p in pictures] == list(range(40))
    named = [p.index for p in pictures if p.damaged]
    assert named == list(range(7, 20))
    assert "changed suddenly" in pictures[7].damaged
    for before in range(7):
        assert np.array_equal(pictures[before].image, clean[before].image)
    assert "HEVC" in damage_detection_note(video)


def test_the_check_runs_only_where_the_decoder_is_silent(tmp_path, monkeypatch):
    """H.264's decoder names damage itself: its frames are not compared (no cost, and no
    false alarm from the check)."""
    import harborsight.flight.sudden_change as sudden_change

    compared = []
    monkeypatch.setattr(sudden_change.SuddenChange, "check",
                        lambda self, grey: compared.append(grey.shape))
    h264 = tmp_path / "h264.mp4"
    _encode(h264, "libx264", {}, _frames(5), "gray")
    assert len(list(read_video_frames(h264))) == 5 and compared == []
    hevc = tmp_path / "hevc.mp4"
    _write_hevc(hevc, n=5)
    assert len(list(read_video_frames(hevc))) == 5 and compared == [(HEIGHT, WIDTH)] * 5


def test_frames_of_any_shape_and_format_are_checked_without_stopping_the_video():
    """A frame 500 times taller than wide made a thumbnail OpenCV cannot shift (a second
    read: `run` stopped, the live reader reopened the stream for ever)."""
    import av

    from harborsight.flight.sudden_change import reduced_grey

    rng = np.random.default_rng(0)
    for width, height, fmt in ((8, 4000, "gray"), (4000, 8, "gray"), (1, 1, "gray"),
                               (64, 36, "yuv420p10le"), (64, 36, "nv12")):
        frame = (av.VideoFrame.from_ndarray(rng.integers(0, 256, (height, width), np.uint8),
                                            format="gray")
                 if fmt == "gray" else av.VideoFrame(width, height, fmt))
        assert max(reduced_grey(frame).shape) == 320
        check = SuddenChange()
        assert [check.check_frame(frame) for _ in range(8)] == [None] * 8
