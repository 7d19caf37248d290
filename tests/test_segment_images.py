"""``harborsight segment`` (perception.segment_images): tiling, blending, files written and
skipped; ``evaluate segmentation --mode tiles`` and ``--predictions``.

The model is a tiny ONNX graph whose logits are the pixel's own B, G, R values, so the
labels of any image are known exactly: blue -> water, green -> ship, red -> obstacle."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.evaluation.segmentation import evaluate_segmentation
from harborsight.perception.default_model import load_onnx_segmenter
from harborsight.perception.segment_images import (
    SegmentMode,
    SegmentOptions,
    collect_images,
    labels_from_logits,
    model_batch,
    natural_key,
    segment_images,
    segment_labels,
    tent_weights,
    tile_starts,
    tiled_logits,
)

runner = CliRunner()
HELDOUT_MIOU = 0.8765


def colour_model(path: Path, batch: int | str = 1, height: int = 360, width: int = 640,
                 bias: np.ndarray | None = None) -> Path:
    """ONNX graph image (N, H, W, 3) uint8 -> logits = the image as float, channels first
    (plus ``bias`` (3, H, W), if given: a model that knows left from right); labels = their
    argmax. ``batch``: a fixed size or a name (free)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    chw = "logits" if bias is None else "chw"
    nodes = [helper.make_node("Cast", ["image"], ["x"], to=TensorProto.FLOAT),
             helper.make_node("Transpose", ["x"], [chw], perm=[0, 3, 1, 2])]
    initializers = []
    if bias is not None:
        nodes.append(helper.make_node("Add", [chw, "bias"], ["logits"]))
        initializers.append(numpy_helper.from_array(bias[None].astype(np.float32), "bias"))
    nodes += [helper.make_node("ArgMax", ["logits"], ["index"], axis=1, keepdims=0),
              helper.make_node("Cast", ["index"], ["labels"], to=TensorProto.UINT8)]
    graph = helper.make_graph(
        nodes, "colour",
        [helper.make_tensor_value_info("image", TensorProto.UINT8, [batch, height, width, 3])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [batch, 3, height, width]),
         helper.make_tensor_value_info("labels", TensorProto.UINT8, [batch, height, width])],
        initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "harborsight", json.dumps({"network": "colour-test"})
    onnx.save(model, str(path))
    path.with_suffix(".json").write_text(json.dumps({
        "schema": "harborsight.model/1", "network": "colour-test",
        "classes": {"0": "water", "1": "ship", "2": "obstacle"},
        "heldout": {"miou": HELDOUT_MIOU, "frames": 3, "data": ["bench"]}}))
    return path


@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    return colour_model(tmp_path_factory.mktemp("model") / "colour.onnx")


@pytest.fixture(scope="module")
def segmenter(model_path):
    return load_onnx_segmenter(model_path)


def random_image(width: int, height: int, seed: int = 0) -> np.ndarray:
    """Random BGR pixels whose largest channel is unique (no ties to break)."""
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 200, (height, width, 3), dtype=np.uint8)
    winner = rng.integers(0, 3, (height, width))
    np.put_along_axis(image, winner[..., None], 230, axis=2)
    return image


def expected_labels(image: np.ndarray) -> np.ndarray:
    return image.argmax(axis=2).astype(np.uint8)


# --- tiling ---------------------------------------------------------------------------------

@pytest.mark.parametrize("length", [1, 9, 17, 256, 359, 360, 361, 600, 640, 641, 700, 800, 1000,
                                    4000])
@pytest.mark.parametrize("window", [360, 640])
@pytest.mark.parametrize("overlap", [0.0, 0.25, 0.5])
def test_windows_cover_every_pixel_and_end_flush_with_the_edge(length, window, overlap):
    starts = tile_starts(length, window, overlap)
    assert starts[0] == 0
    if length <= window:
        assert starts == [0]
        return
    assert starts[-1] == length - window
    steps = np.diff(starts)
    assert (steps > 0).all()
    assert (steps <= math.floor(window * (1 - overlap)) + 1).all()   # at least the overlap asked
    covered = np.zeros(length, bool)
    for start in starts:
        covered[start:start + window] = True
    assert covered.all()


def test_blending_weights_are_positive_and_normalised():
    weights = tent_weights(360, 640)
    assert weights.min() > 0 and weights.dtype == np.float32
    assert weights[0, 0] == pytest.approx(1 / (360 * 640), rel=1e-5)
    assert weights[180, 320] > weights[180, 0] and weights[180, 320] > weights[0, 320]
    for height, width in [(9, 17), (256, 256), (600, 800), (700, 1000), (13, 20)]:
        image = np.zeros((height, width, 3), np.uint8)
        calls = []

        def run(windows, calls=calls):
            calls.append(len(windows))
            return np.full((len(windows), 3, 360, 640), 2.5, np.float32)

        blended = tiled_logits(image, run, (360, 640), 0.25, batch=2)
        assert blended.shape == (3, height, width)
        assert np.isfinite(blended).all()
        np.testing.assert_allclose(blended, 2.5, rtol=1e-6)   # a weighted mean of 2.5s
        assert max(calls) <= 2


def test_blend_is_the_tent_weighted_mean_of_the_windows():
    """Each window answers a constant (its number): a pixel seen by one window gets that
    window's number, one seen by several the tent-weighted mean, computed here by brute force."""
    height, width, win_h, win_w = 13, 20, 6, 8
    image = np.zeros((height, width, 3), np.uint8)
    seen = []

    def run(windows):
        out = np.empty((len(windows), 1, win_h, win_w), np.float32)
        for k in range(len(windows)):
            out[k] = len(seen)
            seen.append(len(seen))
        return out

    blended = tiled_logits(image, run, (win_h, win_w), 0.5, batch=1)[0]
    ys, xs = tile_starts(height, win_h, 0.5), tile_starts(width, win_w, 0.5)
    tent_y = 1 - np.abs(2 * (np.arange(win_h) + 0.5) / win_h - 1)
    tent_x = 1 - np.abs(2 * (np.arange(win_w) + 0.5) / win_w - 1)
    total, weight = np.zeros((height, width)), np.zeros((height, width))
    for k, (y, x) in enumerate((y, x) for y in ys for x in xs):
        w = np.outer(tent_y, tent_x)
        total[y:y + win_h, x:x + win_w] += k * w
        weight[y:y + win_h, x:x + win_w] += w
    np.testing.assert_allclose(blended, total / weight, rtol=1e-5, atol=1e-5)
    assert blended[0, 0] == 0.0 and blended[-1, -1] == len(seen) - 1


def test_labels_from_logits_is_argmax_at_any_size():
    rng = np.random.default_rng(1)
    logits = rng.normal(size=(3, 9, 17)).astype(np.float32)
    assert np.array_equal(labels_from_logits(logits, 17, 9), logits.argmax(0))
    big = labels_from_logits(logits, 170, 90)
    reference = cv2.resize(np.ascontiguousarray(logits.transpose(1, 2, 0)), (170, 90),
                           interpolation=cv2.INTER_LINEAR).argmax(2)
    assert big.dtype == np.uint8 and np.array_equal(big, reference)
    tied = np.zeros((3, 4, 5), np.float32)
    tied[2] = -1.0
    assert (labels_from_logits(tied, 5, 4) == 0).all()     # ties to the lower class, as argmax


@pytest.mark.parametrize(("width", "height"), [(256, 256), (800, 600), (1000, 700), (17, 9),
                                               (640, 360)])
def test_tiles_reproduce_the_exact_labels_at_the_image_size(segmenter, width, height):
    image = random_image(width, height)
    info: dict = {}
    labels = segment_labels(segmenter, image, SegmentOptions(SegmentMode.tiles), info)
    assert labels.shape == (height, width) and labels.dtype == np.uint8
    assert np.array_equal(labels, expected_labels(image))
    assert info["processed"] == [width, height]
    assert info["windows"] == (len(tile_starts(height, 360, 0.25))
                               * len(tile_starts(width, 640, 0.25)))
    resized = segment_labels(segmenter, image, SegmentOptions(SegmentMode.resize))
    assert resized.shape == (height, width) and resized.dtype == np.uint8


def test_tile_scale_and_max_side_keep_the_image_size(segmenter):
    image = np.zeros((700, 1000, 3), np.uint8)
    image[:, :500] = (220, 10, 10)     # water on the left, obstacle on the right
    image[:, 500:] = (10, 10, 220)
    truth = expected_labels(image)
    for options in (SegmentOptions("tiles", tile_scale=0.5), SegmentOptions("tiles", max_side=300),
                    SegmentOptions("tiles", tile_scale=1.7, tile_overlap=0.5)):
        info: dict = {}
        labels = segment_labels(segmenter, image, options, info)
        assert labels.shape == (700, 1000)
        assert (labels == truth).mean() > 0.99
        assert max(info["processed"]) == {0.5: 500, 1.0: 300, 1.7: 1700}[
            options.tile_scale if options.max_side is None else 1.0]


def test_windows_go_in_batches_when_the_model_allows(tmp_path, segmenter):
    free = load_onnx_segmenter(colour_model(tmp_path / "free.onnx", batch="N"))
    fixed2 = load_onnx_segmenter(colour_model(tmp_path / "fixed2.onnx", batch=2))
    assert model_batch(segmenter) == 1 and model_batch(free) is None and model_batch(fixed2) == 2
    image = random_image(1000, 700, seed=3)       # 2 x 3 windows
    for model, options, sizes in ((segmenter, SegmentOptions("tiles", batch_size=4), [1] * 6),
                                  (free, SegmentOptions("tiles", batch_size=4), [4, 2]),
                                  (fixed2, SegmentOptions("tiles", batch_size=5), [2, 2, 2])):
        batches = []
        session = model.session

        class Counting:
            def get_inputs(self, session=session):
                return session.get_inputs()

            def run(self, names, feed, session=session, batches=batches):
                batches.append(len(feed["image"]))
                return session.run(names, feed)

        model.session = Counting()
        try:
            labels = segment_labels(model, image, options)
        finally:
            model.session = session
        assert batches == sizes
        assert np.array_equal(labels, expected_labels(image))


def test_options_refuse_tile_settings_in_resize_mode():
    with pytest.raises(InputError, match="--tile-overlap: --tile-overlap is for --mode tiles"):
        SegmentOptions.from_options("resize", tile_overlap=0.5)
    assert SegmentOptions.from_options("tiles").to_dict() == {
        "mode": "tiles", "tile_overlap": 0.25, "tile_scale": 1.0, "max_side": None}
    with pytest.raises(InputError, match="--tile-scale"):
        SegmentOptions("tiles", tile_scale=0.0)


@pytest.mark.parametrize("width, height, scale", [(256, 256, 360 / 256), (640, 360, 1.0),
                                                   (320, 90, 2.0), (800, 600, None),
                                                   (700, 300, None)])
def test_auto_enlarges_small_frames_and_stretches_large_ones(segmenter, width, height, scale):
    """A frame no larger than the 640x360 input is enlarged without stretching until it fills
    the input in one dimension, then padded into one window; a larger one is stretched."""
    image = random_image(width, height, seed=5)
    info: dict = {}
    labels = segment_labels(segmenter, image, SegmentOptions(SegmentMode.auto), info)
    assert info["windows"] == 1
    if scale is None:
        assert np.array_equal(labels, segment_labels(segmenter, image, SegmentOptions(SegmentMode.resize)))
    else:
        as_tiles = segment_labels(segmenter, image, SegmentOptions(SegmentMode.tiles, tile_scale=scale))
        assert np.array_equal(labels, as_tiles) and labels.shape == (height, width)
        assert info["processed"] == [round(width * scale), round(height * scale)]
        assert max(info["processed"][0] / 640, info["processed"][1] / 360) == pytest.approx(1.0)
        if scale == 1.0:  # the frame's own pixels, not a resampled copy: exact labels
            assert np.array_equal(labels, expected_labels(image))
    assert SegmentOptions.from_options("auto").to_dict() == {"mode": "auto"}
    with pytest.raises(InputError, match="--tile-scale is for --mode tiles"):
        SegmentOptions.from_options("auto", tile_scale=0.5)


# --- finding and writing --------------------------------------------------------------------

# --- test-time flips ------------------------------------------------------------------------

def _softmax(logits: np.ndarray) -> np.ndarray:
    e = np.exp(logits - logits.max(axis=0))
    return e / e.sum(axis=0)


def test_flips_average_the_probabilities_of_the_flipped_copies(tmp_path):
    """A model that knows left from right and up from down (a ramp added to the ship and
    obstacle logits): with flips the result is the mean of the softmax of each flipped
    copy, flipped back (numpy by hand), and the labels turn with the frame."""
    height, width = 36, 64
    bias = np.zeros((3, height, width))
    bias[1] = np.linspace(-6, 6, width)[None, :] + 0.137   # ship to the right
    bias[2] = np.linspace(-4, 4, height)[:, None] + 0.291  # obstacle to the bottom
    seg = load_onnx_segmenter(colour_model(tmp_path / "ramp.onnx", 1, height, width, bias))
    image = np.random.default_rng(5).integers(0, 12, (height, width, 3), dtype=np.uint8)
    x = image.transpose(2, 0, 1).astype(float)
    copies = {1: [(False, False)], 2: [(False, False), (True, False)],
              4: [(False, False), (True, False), (False, True), (True, True)]}
    for flips, views in copies.items():
        expected = np.zeros((3, height, width))
        for mirror, upside_down in views:
            flipped = x[:, ::-1 if upside_down else 1, ::-1 if mirror else 1]
            p = _softmax(flipped + bias)
            expected += p[:, ::-1 if upside_down else 1, ::-1 if mirror else 1] / len(views)
        got = np.exp(seg.batch_logits(image[None], flips)[0])
        if flips == 1:
            got = _softmax(np.log(got))
        np.testing.assert_allclose(got, expected, atol=1e-5)
        labels = seg.segment(image, flips)
        top_two = np.sort(expected, axis=0)[-2:]
        clear = top_two[1] - top_two[0] > 1e-4             # no near-tie for float32 to break
        assert clear.mean() > 0.99
        assert np.array_equal(labels[clear], expected.argmax(axis=0)[clear])
        # the same labels in tiles mode, where the windows go through the flips too
        assert np.array_equal(segment_labels(seg, image, SegmentOptions("tiles", flips=flips)), labels)
    for turn in (lambda a: a[:, ::-1], lambda a: a[::-1]):           # mirror, upside down
        four = seg.segment(image, 4)
        assert np.array_equal(seg.segment(np.ascontiguousarray(turn(image)), 4), turn(four))
        one = seg.segment(image, 1)
        assert not np.array_equal(seg.segment(np.ascontiguousarray(turn(image)), 1), turn(one))
    with pytest.raises(InputError, match="--flips"):
        SegmentOptions(flips=3)
    with pytest.raises(InputError, match="--flips"):
        seg.segment(image, 3)


def test_segment_and_evaluate_take_flips(model_path, tmp_path):
    image = random_image(640, 360, seed=3)
    (tmp_path / "in").mkdir()
    cv2.imwrite(str(tmp_path / "in" / "f.png"), image)
    out = tmp_path / "out"
    result = runner.invoke(app, ["segment", str(tmp_path / "in"), "--out", str(out), "--model",
                                 str(model_path), "--flips", "4", "--mode", "resize"],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "with its mirror images" in result.output
    summary = json.loads((out / "segment.json").read_text())
    assert summary["mode"]["mode"] == "resize" and summary["mode"]["flips"] == 4
    mask = cv2.imread(str(out / "f.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(mask, expected_labels(image))      # a pixel-wise model: flips agree
    result = runner.invoke(app, ["segment", str(tmp_path / "in"), "--out", str(out), "--model",
                                 str(model_path), "--flips", "3"], terminal_width=200)
    assert result.exit_code == 2 and "--flips" in result.output
    data = write_dataset(tmp_path / "data", {"f": (image, expected_labels(image))})
    report = tmp_path / "e.json"
    result = runner.invoke(app, ["evaluate", "segmentation", "--model", str(model_path), "--data",
                                 str(data), "--flips", "2", "--json", str(report), "--fps-seconds",
                                 "0", "--height-bin-m", "0"], terminal_width=200)
    assert result.exit_code == 0, result.output
    written = json.loads(report.read_text())
    assert written["mode"] == {"mode": "auto", "flips": 2}     # an ONNX model's default
    assert written["splits"]["test"]["miou"] == pytest.approx(1.0)
    result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(data), "--predictions",
                                 str(out), "--flips", "2"], terminal_width=200)
    assert result.exit_code == 2 and "--flips" in result.output


def test_natural_order_and_suffixes(tmp_path):
    names = ["frame_10.png", "frame_2.PNG", "Frame_1.jpeg", "x.TIF", "y.tiff", "z.JPG",
             "notes.txt", ".hidden.png"]
    for name in names:
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "deep.png").write_bytes(b"")
    found = [p.name for p in collect_images([tmp_path])]
    assert found == ["Frame_1.jpeg", "frame_2.PNG", "frame_10.png", "x.TIF", "y.tiff", "z.JPG"]
    assert "deep.png" in [p.name for p in collect_images([tmp_path], recursive=True)]
    assert sorted(["b10", "b9", "a"], key=natural_key) == ["a", "b9", "b10"]
    # a file named twice counts once; a file named on its own is taken whatever its suffix
    assert collect_images([tmp_path / "notes.txt", tmp_path / "notes.txt"]) == [tmp_path / "notes.txt"]
    with pytest.raises(InputError, match="no such file"):
        collect_images([tmp_path / "absent.png"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no image files"):
        collect_images([tmp_path / "empty"])


def write_inputs(folder: Path) -> dict[str, np.ndarray]:
    """Good images of several sizes and formats, and broken files."""
    folder.mkdir(parents=True)
    images = {"frame_10.png": random_image(800, 600, 1), "frame_2.png": random_image(17, 9, 2),
              "tile.TIFF": random_image(256, 256, 3), "a.png": random_image(30, 20, 4),
              "a.jpg": random_image(40, 20, 5)}
    for name, image in images.items():
        assert cv2.imwrite(str(folder / name), image)
    (folder / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    (folder / "empty.jpg").write_bytes(b"")
    (folder / "bad.tif").write_bytes(b"II*\x00" + b"\x00" * 20)
    return images


def test_segment_command_writes_masks_overlays_and_a_summary(model_path, tmp_path):
    images = write_inputs(tmp_path / "in")
    out = tmp_path / "out"
    result = runner.invoke(app, ["segment", str(tmp_path / "in"), "--out", str(out),
                                 "--model", str(model_path), "--overlay", "--mode", "tiles"],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    assert f"segmenting with {model_path}" in result.output
    assert "5 mask(s) written" not in result.output and "4 mask(s) written" in result.output
    assert "4 image(s) left out" in result.output
    for name in ("broken.png", "empty.jpg", "bad.tif"):
        assert name in result.output
    summary = json.loads((out / "segment.json").read_text())
    assert summary["schema"] == "harborsight.segment/1"
    assert summary["model"]["path"] == str(model_path)
    assert summary["model"]["network"] == "colour-test"
    assert summary["model"]["heldout_miou"] == HELDOUT_MIOU
    assert summary["mode"]["mode"] == "tiles" and summary["mode"]["tile_overlap"] == 0.25
    assert summary["mode"]["window"] == {"width": 640, "height": 360}
    # natural order; a.jpg comes before a.png and takes the stem
    assert [Path(i["input"]).name for i in summary["images"]] == [
        "a.jpg", "frame_2.png", "frame_10.png", "tile.TIFF"]
    skipped = {Path(s["input"]).name: s["reason"] for s in summary["skipped"]}
    assert set(skipped) == {"a.png", "bad.tif", "broken.png", "empty.jpg"}
    assert "a.jpg" in skipped["a.png"] and "overwritten" in skipped["a.png"]
    assert "cannot decode" in skipped["broken.png"]
    for entry in summary["images"]:
        name = Path(entry["input"]).name
        mask_file = Path(entry["mask"])
        assert mask_file == out / f"{Path(name).stem}.png"
        header = mask_file.read_bytes()[:26]
        assert header[24] == 8 and header[25] == 0          # 8-bit greyscale PNG
        mask = cv2.imread(str(mask_file), cv2.IMREAD_UNCHANGED)
        assert mask.ndim == 2 and mask.dtype == np.uint8
        assert (entry["width"], entry["height"]) == (mask.shape[1], mask.shape[0])
        if name != "a.jpg":  # lossless inputs: the exact colour labels
            assert np.array_equal(mask, expected_labels(images[name]))
        assert sum(entry["fractions"].values()) == pytest.approx(1.0)
        assert entry["fractions"]["water"] == pytest.approx(float((mask == 0).mean()))
        assert entry["time_ms"] >= 0
        picture = cv2.imread(entry["overlay"], cv2.IMREAD_UNCHANGED)
        assert picture.shape == (*mask.shape, 3)
    assert not list(out.rglob("*.part"))


def test_overlay_has_the_class_colours_and_a_legend(model_path, tmp_path):
    image = np.zeros((400, 600, 3), np.uint8)
    image[:, :200] = (200, 0, 0)
    image[:, 200:400] = (0, 200, 0)
    image[:, 400:] = (0, 0, 200)
    (tmp_path / "in").mkdir()
    cv2.imwrite(str(tmp_path / "in" / "three.png"), image)
    out = tmp_path / "out"
    result = runner.invoke(app, ["segment", str(tmp_path / "in" / "three.png"), "--out", str(out),
                                 "--model", str(model_path), "--overlay"])
    assert result.exit_code == 0, result.output
    picture = cv2.imread(str(out / "overlays" / "three.jpg"))
    from harborsight.perception.segment_images import OVERLAY_ALPHA, OVERLAY_COLOURS_BGR

    for class_id, column in ((0, 100), (1, 300), (2, 500)):
        expected = ((1 - OVERLAY_ALPHA) * image[300, column]
                    + OVERLAY_ALPHA * np.array(OVERLAY_COLOURS_BGR[class_id]))
        assert np.abs(picture[300, column].astype(float) - expected).max() < 12
    legend, below = picture[6:36, 6:90].sum(axis=2), picture[306:336, 6:90].sum(axis=2)
    assert np.median(legend) < 0.5 * np.median(below)      # the darkened legend box
    assert (legend > 600).any()                            # with white text


def test_all_unreadable_exits_1_and_usage_errors_exit_2(model_path, tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    out = tmp_path / "out"
    result = runner.invoke(app, ["segment", str(bad), "--out", str(out), "--model", str(model_path)])
    assert result.exit_code == 1
    assert json.loads((out / "segment.json").read_text())["skipped"][0]["input"] == str(bad)
    result = runner.invoke(app, ["segment", str(bad), "--out", str(out),
                                 "--model", str(tmp_path / "missing.onnx")])
    assert result.exit_code == 2 and "missing.onnx" in result.output
    result = runner.invoke(app, ["segment", str(tmp_path / "nothing.png"), "--out", str(out),
                                 "--model", str(model_path)])
    assert result.exit_code == 2 and "no such file" in result.output
    result = runner.invoke(app, ["segment", str(bad), "--out", str(out), "--model",
                                 str(model_path), "--tile-overlap", "0.5"])
    assert result.exit_code == 2 and "--mode tiles" in result.output


def test_a_mask_never_replaces_an_input_image(segmenter, tmp_path):
    cv2.imwrite(str(tmp_path / "photo.png"), random_image(20, 10))
    before = (tmp_path / "photo.png").read_bytes()
    run = segment_images(collect_images([tmp_path]), segmenter, tmp_path)
    assert not run.images and "input images" in run.skipped[0][1]
    assert (tmp_path / "photo.png").read_bytes() == before


# --- evaluate segmentation ------------------------------------------------------------------

def write_dataset(root: Path, frames: dict[str, tuple[np.ndarray, np.ndarray]]) -> Path:
    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    for stem, (image, labels) in frames.items():
        cv2.imwrite(str(root / "images" / f"{stem}.png"), image)
        cv2.imwrite(str(root / "labels" / f"{stem}.png"), labels)
    (root / "dataset.json").write_text(json.dumps({"split": dict.fromkeys(frames, "test")}))
    return root


def test_evaluate_predictions_scores_written_masks(tmp_path):
    labels = np.array([[0, 0, 1], [2, 255, 1]], np.uint8)
    predicted = np.array([[0, 1, 1], [2, 0, 0]], np.uint8)    # mIoU 5/9, by hand in
    image = np.zeros((2, 3, 3), np.uint8)                       # test_segmentation_eval
    other = np.array([[2, 2, 0], [1, 1, 0]], np.uint8)
    data = write_dataset(tmp_path / "data", {"f1": (image, labels), "f2": (image, other),
                                             "f3": (image, other), "f4": (image, other)})
    masks = tmp_path / "masks"
    masks.mkdir()
    cv2.imwrite(str(masks / "f1.png"), labels.clip(0, 2))      # 255 pixels are not scored
    cv2.imwrite(str(masks / "f2.png"), other)
    result = evaluate_segmentation(None, [data], ["test"], fps_seconds=0, height_bin_m=0,
                                   predictions=masks)
    # f3 (missing) and f4 (missing) are left out
    row = result.rows[0]
    assert row.frames == 2 and row.scores.miou == pytest.approx(1.0)
    assert sorted(Path(p).name for p, _ in row.skipped) == ["f3.png", "f4.png"]
    assert result.to_dict()["mode"] == {"mode": "predictions", "predictions": str(masks)}

    cv2.imwrite(str(masks / "f1.png"), predicted)
    cv2.imwrite(str(masks / "f3.png"), np.zeros((3, 2), np.uint8))    # wrong size
    (masks / "f2.png").unlink()
    cv2.imwrite(str(masks / "f4.png"), np.full((2, 3), 7, np.uint8))  # not a class
    out = tmp_path / "e.json"
    result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(data), "--predictions",
                                 str(masks), "--json", str(out), "--height-bin-m", "0"],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())["splits"]["test"]
    assert report["frames"] == 1 and report["miou"] == pytest.approx(5 / 9)
    assert report["iou"] == pytest.approx({"water": 1 / 3, "ship": 1 / 3, "obstacle": 1.0})
    reasons = {Path(s["path"]).name: s["error"] for s in report["skipped_frames"]}
    assert set(reasons) == {"f2.png", "f3.png", "f4.png"}
    assert "differs from the frame's 3x2" in reasons["f3.png"]
    assert "class ids" in reasons["f4.png"]
    assert "skipped" in result.output and "f3.png" in result.output
    result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(data)])
    assert result.exit_code == 2 and "--predictions" in result.output


def test_evaluate_a_model_in_tiles_mode(model_path, tmp_path):
    frames = {}
    for k, (w, h) in enumerate([(800, 600), (17, 9)]):
        image = random_image(w, h, seed=10 + k)
        frames[f"f{k}"] = (image, expected_labels(image))
    data = write_dataset(tmp_path / "data", frames)
    out = tmp_path / "e.json"
    result = runner.invoke(app, ["evaluate", "segmentation", "--model", str(model_path),
                                 "--data", str(data), "--mode", "tiles", "--tile-overlap", "0.3",
                                 "--json", str(out), "--fps-seconds", "0", "--height-bin-m", "0"],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["mode"] == {"mode": "tiles", "tile_overlap": 0.3, "tile_scale": 1.0,
                              "max_side": None}
    assert report["splits"]["test"]["miou"] == pytest.approx(1.0)
    result = runner.invoke(app, ["evaluate", "segmentation", "--model", str(model_path),
                                 "--data", str(data), "--json", str(out), "--fps-seconds", "0",
                                 "--height-bin-m", "0", "--mode", "resize"])
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["mode"] == {"mode": "resize"} and report["splits"]["test"]["miou"] < 1.0
    # without --mode an ONNX model is scored as segment writes its masks: auto
    result = runner.invoke(app, ["evaluate", "segmentation", "--model", str(model_path),
                                 "--data", str(data), "--json", str(out), "--fps-seconds", "0",
                                 "--height-bin-m", "0"])
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["mode"] == {"mode": "auto"}


def test_exact_int8_gives_the_graphs_labels_and_says_so(tmp_path):
    """``segment --exact-int8`` and ``evaluate segmentation --exact-int8`` run an int8 graph
    as written: a model whose fused arithmetic saturates on CPUs without VNNI still labels
    a white frame ship, and segment.json / the evaluation JSON record how it ran."""
    from tests.int8_models import HEIGHT, WIDTH, saturating_qdq_model

    model = saturating_qdq_model(tmp_path / "sat.onnx")
    white = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    (tmp_path / "in").mkdir()
    cv2.imwrite(str(tmp_path / "in" / "white.png"), white)
    out = tmp_path / "out"
    result = runner.invoke(app, ["segment", str(tmp_path / "in"), "--out", str(out), "--model",
                                 str(model), "--exact-int8"])
    assert result.exit_code == 0, result.output
    assert (cv2.imread(str(out / "white.png"), cv2.IMREAD_UNCHANGED) == 1).all()
    assert json.loads((out / "segment.json").read_text())["model"]["int8_arithmetic"] == "reference"

    data = write_dataset(tmp_path / "data", {"white": (white, np.ones((HEIGHT, WIDTH), np.uint8))})
    report = tmp_path / "e.json"
    for flag, arithmetic in (("--exact-int8", "reference"), ("--no-exact-int8", "fused")):
        result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(data), "--model",
                                     str(model), "--json", str(report), "--height-bin-m", "0",
                                     "--fps-seconds", "0", flag], terminal_width=200)
        assert result.exit_code == 0, result.output
        written = json.loads(report.read_text())
        assert written["mode"]["int8_arithmetic"].startswith(arithmetic)
        # fused kernels too give the graph's labels (uint8 weights where int8 saturates)
        assert written["splits"]["test"]["miou"] == pytest.approx(1.0)


def test_recursive_masks_mirror_the_subfolders(model_path, tmp_path):
    """A drone restarts its numbering in each folder (100MEDIA/DJI_0001.JPG,
    101MEDIA/DJI_0001.JPG): with --recursive the masks were named by file name alone, and all
    but one of each name were left out. They now go in the same subfolders of --out; a file
    of the folder itself keeps its plain name."""
    rng = np.random.default_rng(3)
    for where in ("100MEDIA/DJI_0001.JPG", "101MEDIA/DJI_0001.JPG", "top.png"):
        path = tmp_path / "in" / where
        path.parent.mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(path), rng.integers(0, 256, (36, 64, 3), dtype=np.uint8))
    out = tmp_path / "out"
    result = runner.invoke(app, ["segment", str(tmp_path / "in"), "--out", str(out), "--recursive",
                                 "--model", str(model_path), "--overlay"], terminal_width=200)
    assert result.exit_code == 0, result.output
    for mask in ("100MEDIA/DJI_0001.png", "101MEDIA/DJI_0001.png", "top.png"):
        assert cv2.imread(str(out / mask), cv2.IMREAD_UNCHANGED).shape == (36, 64)
    assert (out / "overlays" / "101MEDIA" / "DJI_0001.jpg").is_file()
    assert json.loads((out / "segment.json").read_text())["skipped"] == []


def test_a_model_of_another_number_of_classes_is_refused_when_loaded(tmp_path):
    """A model with a fourth output class and no class names in its sidecar or metadata was
    loaded, and its class ids 3 stopped `evaluate segmentation` half way with a traceback.
    Its logits' channels are checked when it is loaded."""
    from onnx import TensorProto, helper, numpy_helper

    nodes = [helper.make_node("Cast", ["image"], ["x"], to=TensorProto.FLOAT),
             helper.make_node("Transpose", ["x"], ["chw"], perm=[0, 3, 1, 2]),
             helper.make_node("Concat", ["chw", "extra"], ["logits"], axis=1),
             helper.make_node("ArgMax", ["logits"], ["index"], axis=1, keepdims=0),
             helper.make_node("Cast", ["index"], ["labels"], to=TensorProto.UINT8)]
    graph = helper.make_graph(
        nodes, "four", [helper.make_tensor_value_info("image", TensorProto.UINT8, [1, 36, 64, 3])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 4, 36, 64]),
         helper.make_tensor_value_info("labels", TensorProto.UINT8, [1, 36, 64])],
        [numpy_helper.from_array(np.zeros((1, 1, 36, 64), np.float32), "extra")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    import onnx

    onnx.save(model, str(tmp_path / "four.onnx"))
    with pytest.raises(InputError, match="'logits' has 4 classes"):
        load_onnx_segmenter(tmp_path / "four.onnx")


def test_the_measuring_pipelines_segment_a_small_frame_as_segment_does(segmenter, tmp_path):
    """`run`, `live` and `evaluate distance` stretched a frame no larger than the model
    input into it, where `segment --mode auto` enlarges it without stretching and pads it
    (a 256x256 marina tile: 62.3 against 65.4 % mIoU on the val split). The labels and the
    probabilities the clearance reads now come from the same enlarged, padded window; a
    frame of the input's size or larger is stretched as before."""
    from harborsight.pipeline import frame_labels

    tile = random_image(256, 256, seed=3)
    mask = frame_labels(tile, None, segmenter, "tile")
    auto = segment_labels(segmenter, tile, SegmentOptions(SegmentMode.auto))
    np.testing.assert_array_equal(mask.labels, auto)
    centres = np.array([[10.0, 20.0], [128.0, 128.0], [250.0, 3.0]])
    solid = mask.confidence.solid_probability(centres)
    assert solid.shape == (3,) and np.isfinite(solid).all()
    frame = random_image(640, 360, seed=4)
    whole = frame_labels(frame, None, segmenter, "frame")
    np.testing.assert_array_equal(whole.labels, segmenter.segment(frame))
