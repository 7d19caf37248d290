"""Segmenting at a chosen ground sample distance (harborsight.perception.gsd_scaling)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.frame import load_frame_metadata
from harborsight.perception.default_model import load_onnx_segmenter
from harborsight.perception.gsd_scaling import (
    GsdScaledSegmenter,
    check_segment_gsd,
    processing_scale,
)
from harborsight.pipeline import frame_gsd_m_per_px, frame_labels
from tests.helpers import copy_sample_frames
from tests.test_segment_images import colour_model

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
runner = CliRunner()


@pytest.fixture(scope="module")
def colour_segmenter(tmp_path_factory):
    return load_onnx_segmenter(colour_model(tmp_path_factory.mktemp("model") / "colour.onnx"))


def test_processing_scale_by_hand():
    # 640x360 from 100 m with fx 454.66: 0.21994 m/px; to 0.11 m/px is twice as large
    gsd = 100.0 / 454.66
    assert processing_scale(640, 360, gsd, 0.11, 640, 360) == pytest.approx(gsd / 0.11)
    # already that fine: the one-call path (None), also within the 5 % tolerance
    assert processing_scale(640, 360, 0.10, 0.11, 640, 360) is None
    assert processing_scale(640, 360, 0.115, 0.11, 640, 360) is None
    # a 1920x1080 frame from 100 m at fx 1364: 0.0733 m/px, stretched into 640x360 it reaches
    # the model at 0.22 m/px; to see 0.1 m/px it is shrunk to 0.733 of its size, not enlarged
    assert processing_scale(1920, 1080, 0.0733, 0.1, 640, 360) == pytest.approx(0.733)
    # a 4:3 photo stretched into 16:9 loses most across its height (3000/360 = 8.33): at
    # 0.012 m/px it reaches the model at 0.1 (the one-call path), at 0.015 at 0.125
    assert processing_scale(4000, 3000, 0.012, 0.1, 640, 360) is None
    assert processing_scale(4000, 3000, 0.015, 0.1, 640, 360) == pytest.approx(0.15)
    # capped: the scaled frame's longer side at most three model inputs (1920 px)
    assert processing_scale(640, 360, 1.0, 0.1, 640, 360) == pytest.approx(3.0)
    for unknown in (None, math.nan, 0.0, -1.0, math.inf):
        assert processing_scale(640, 360, unknown, 0.1, 640, 360) is None


def test_the_option_is_off_at_zero_and_refuses_nonsense():
    assert check_segment_gsd(0) is None and check_segment_gsd(None) is None
    assert check_segment_gsd(0.12) == 0.12
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(InputError, match="--segment-gsd-m"):
            check_segment_gsd(bad)


def _blocks(width: int, height: int, block: int = 40, seed: int = 3) -> np.ndarray:
    """A BGR picture of ``block``-pixel squares, each with one clearly largest channel."""
    rng = np.random.default_rng(seed)
    winners = rng.integers(0, 3, (height // block + 1, width // block + 1))
    winner = np.kron(winners, np.ones((block, block), int))[:height, :width]
    image = np.full((height, width, 3), 60, np.uint8)
    np.put_along_axis(image, winner[..., None], 220, axis=2)
    return image


def test_a_coarse_frame_is_enlarged_and_tiled_and_its_labels_keep_the_frame_size(colour_segmenter):
    """The colour model's logits are the picture itself, so its labels are the picture's
    largest channel at any scale: the scaled path must give them at the frame's size (away
    from block edges, where the resampling blends neighbours), with the model's confidence
    on the enlarged grid; a fine frame, or one of unknown GSD, takes the one-call path."""
    image = _blocks(640, 360)
    expected = image.argmax(axis=2)
    scaled = GsdScaledSegmenter(colour_segmenter, 1, 0.1)
    labels, confidence = scaled.segment_with_confidence(image, 0.2)
    assert labels.shape == (360, 640) and labels.dtype == np.uint8
    assert (confidence.grid_width, confidence.grid_height) == (1280, 720)
    inner = np.ones((360, 640), bool)
    for edge in range(0, 640, 40):
        inner[:, max(0, edge - 1):edge + 1] = False
    for edge in range(0, 360, 40):
        inner[max(0, edge - 1):edge + 1, :] = False
    assert (labels[inner] == expected[inner]).all()
    # the probabilities read where the labels came from: a block's centre is sure of its class
    centre = np.array([[20.0, 20.0]])
    p_solid = confidence.solid_probability(centre)[0]
    assert (p_solid > 0.5) == (expected[20, 20] != 0)
    for gsd in (0.08, None):
        labels, confidence = scaled.segment_with_confidence(image, gsd)
        plain_labels = colour_segmenter.segment_with_confidence(image)[0]
        assert (labels == plain_labels).all()
        assert (confidence.grid_width, confidence.grid_height) == (640, 360)
    assert (scaled.segment(image, 0.2) == scaled.segment_with_confidence(image, 0.2)[0]).all()
    with pytest.raises(InputError, match="--segment-gsd-m"):
        GsdScaledSegmenter(colour_segmenter, 1, 0)


def test_the_pipeline_hands_the_frame_s_gsd_to_a_segmenter_that_takes_one():
    meta_path = sorted((SAMPLES / "frames").glob("*.json"))[0]
    meta = load_frame_metadata(meta_path)
    raw = json.loads(meta_path.read_text())
    height_m = raw["uav"]["alt_m"] - raw.get("water_level_m", 0.0)
    # the centre pixel's footprint along the tilt: h / (f cos²θ), θ off straight down
    off_nadir = math.radians(90.0 + raw["camera_attitude"]["pitch_deg"])
    by_hand = height_m / min(raw["camera"]["fx"], raw["camera"]["fy"]) / math.cos(off_nadir) ** 2
    assert frame_gsd_m_per_px(meta) == pytest.approx(by_hand, rel=1e-6)
    # straight down: the nadir GSD; near the horizon: capped at 78 degrees off nadir
    nadir = dataclasses.replace(meta, pitch_deg=-90.0, roll_deg=0.0)
    assert frame_gsd_m_per_px(nadir) == pytest.approx(height_m / min(raw["camera"]["fx"],
                                                                      raw["camera"]["fy"]))
    level = dataclasses.replace(meta, pitch_deg=0.0, roll_deg=0.0)
    assert frame_gsd_m_per_px(level) == pytest.approx(frame_gsd_m_per_px(nadir) / 0.2 ** 2)

    seen = []

    class Recorder:
        takes_gsd = True
        path = "recorder.onnx"

        def segment_with_confidence(self, image, gsd_m_per_px):
            seen.append(gsd_m_per_px)
            return np.zeros(image.shape[:2], np.uint8), None

    image = np.zeros((meta.camera.height, meta.camera.width, 3), np.uint8)
    mask = frame_labels(image, None, Recorder(), meta_path, None, meta)
    assert seen == [pytest.approx(by_hand)] and mask.source == "recorder.onnx"
    frame_labels(image, None, Recorder(), meta_path)      # no metadata: no GSD
    assert seen[-1] is None


def test_run_and_evaluate_take_the_option_and_say_so(tmp_path, untrained_model):
    frames = copy_sample_frames(SAMPLES, tmp_path / "frames", 2)
    vessel = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"
    common = ["--vessel", str(vessel), "--no-video", "--no-overlays"]
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(frames), "--model", str(untrained_model),
                                 "--segment-gsd-m", "0.05", "--out", str(out), *common],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "frames coarser than 0.05 m/px enlarged to it" in result.output
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 2 and record["settings"]["segment_gsd_m"] == 0.05
    # off unless given (0 is off too)
    for given, recorded in (([], None), (["--segment-gsd-m", "0"], None)):
        result = runner.invoke(app, ["run", str(frames), "--model", str(untrained_model), *given,
                                     "--out", str(tmp_path / "plain"), *common],
                               terminal_width=200)
        assert result.exit_code == 0, result.output
        assert json.loads((tmp_path / "plain" / "run.json").read_text())["settings"][
            "segment_gsd_m"] == recorded
    for wrong in (["--model", str(untrained_model), "--segment-gsd-m", "-1"],
                  ["--masks", str(SAMPLES / "labels"), "--segment-gsd-m", "0.1"]):
        result = runner.invoke(app, ["run", str(SAMPLES if "--masks" in wrong else frames),
                                     *wrong, "--out", str(tmp_path / "bad"), *common],
                               terminal_width=200)
        assert result.exit_code == 2 and "--segment-gsd-m" in result.output, result.output
    result = runner.invoke(app, ["measure", str(SAMPLES), "--segment-gsd-m", "0.1", "--out",
                                 str(tmp_path / "masked")], terminal_width=200)
    assert result.exit_code == 2 and "--segment-gsd-m" in result.output, result.output
    result = runner.invoke(app, ["measure", str(frames), "--model", str(untrained_model),
                                 "--segment-gsd-m", "0.05", "--vessel", str(vessel), "--out",
                                 str(tmp_path / "measured"), "--no-tables"], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert len(list((tmp_path / "measured").glob("*.json"))) == 2
    result = runner.invoke(app, ["evaluate", "distance", "--data", str(SAMPLES), "--no-oracle",
                                 "--model", str(untrained_model), "--segment-gsd-m", "0.05",
                                 "--methods", "ground_plane", "--limit", "1", "--out",
                                 str(tmp_path / "distance")], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "+gsd0.05" in (tmp_path / "distance" / "sections.csv").read_text()
    result = runner.invoke(app, ["evaluate", "distance", "--data", str(SAMPLES),
                                 "--segment-gsd-m", "0.05", "--out", str(tmp_path / "oracle")],
                           terminal_width=200)
    assert result.exit_code == 2 and "--segment-gsd-m" in result.output, result.output


def test_the_windows_blend_is_mixed_with_the_one_call_view_by_hand(colour_segmenter, monkeypatch):
    """With constant logits from the windows (A) and from the one-call view (B), every pixel
    of the scaled grid holds log((1 - w) softmax(A) + w softmax(B)), w = WHOLE_VIEW_WEIGHT."""
    from harborsight.perception import gsd_scaling, segment_images

    windows_logits = np.array([2.0, 0.0, -1.0], np.float32)
    whole_logits = np.array([-1.0, 3.0, 0.5], np.float32)
    monkeypatch.setattr(segment_images, "scaled_tile_logits", lambda segmenter, image, options:
                        np.broadcast_to(windows_logits[:, None, None], (3, 720, 1280)).copy())
    monkeypatch.setattr(colour_segmenter, "batch_logits", lambda images, flips=1:
                        np.broadcast_to(whole_logits[None, :, None, None], (1, 3, 360, 640)).copy())
    scaled = GsdScaledSegmenter(colour_segmenter, 1, 0.1)
    labels, confidence = scaled.segment_with_confidence(_blocks(640, 360), 0.2)

    def softmax(x):
        e = np.exp(x - x.max())
        return e / e.sum()

    w = gsd_scaling.WHOLE_VIEW_WEIGHT
    expected = (1 - w) * softmax(windows_logits.astype(float)) + w * softmax(whole_logits.astype(float))
    got = confidence.logits_at(np.array([[100.0, 50.0], [639.0, 359.0]]))
    assert np.allclose(np.exp(got), expected[None], atol=1e-5)
    assert (labels == expected.argmax()).all()
    assert confidence.solid_probability(np.array([[3.0, 4.0]]))[0] == pytest.approx(1 - expected[0])


def test_a_small_tile_s_whole_view_is_the_one_its_segmenter_makes(colour_segmenter, monkeypatch):
    """A 256x256 orthophoto tile at 0.3 m/px is enlarged (to 0.1 m/px: 768x768, windows of
    640x360), and its one-call view is the wrapped segmenter's own (enlarged without
    stretching into 360x360 and padded), not a stretch into 640x360."""
    from harborsight.perception import segment_images

    calls = []
    real = segment_images.small_frame_logits

    def spy(segmenter, image, flips=1):
        calls.append(image.shape)
        return real(segmenter, image, flips)

    monkeypatch.setattr(segment_images, "small_frame_logits", spy)
    tile = _blocks(256, 256, block=32)
    scaled = GsdScaledSegmenter(colour_segmenter, 1, 0.1)
    labels, confidence = scaled.segment_with_confidence(tile, 0.3)
    assert calls == [(256, 256, 3)]
    assert labels.shape == (256, 256)
    assert (confidence.grid_width, confidence.grid_height) == (768, 768)
    inner = np.ones((256, 256), bool)
    for edge in range(0, 256, 32):
        inner[:, max(0, edge - 2):edge + 2] = False
        inner[max(0, edge - 2):edge + 2, :] = False
    assert (labels[inner] == tile.argmax(axis=2)[inner]).all()
