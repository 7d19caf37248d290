"""Images cut short or corrupted are refused, not measured: libjpeg fills a truncated JPEG
with grey, which a segmenter calls obstacle (issue #30: a 3.15 m section read 0.43 m)."""

import io
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.images import incomplete_reason, read_image, read_mask

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
runner = CliRunner()


def picture() -> np.ndarray:
    rng = np.random.default_rng(0)
    return cv2.GaussianBlur(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), (5, 5), 0)


def encoded(suffix: str) -> bytes:
    if suffix == ".tif":
        buffer = io.BytesIO()
        Image.fromarray(picture()).save(buffer, format="TIFF")
        return buffer.getvalue()
    ok, data = cv2.imencode(suffix, picture())
    assert ok
    return data.tobytes()


@pytest.mark.parametrize("suffix", [".jpg", ".png", ".tif"])
def test_whole_images_pass_and_cut_ones_are_refused(tmp_path, suffix):
    data = encoded(suffix)
    whole = tmp_path / f"whole{suffix}"
    whole.write_bytes(data)
    assert incomplete_reason(data) is None
    assert read_image(whole).shape == (120, 160, 3)
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: len(data) // 2])
    decoded = cv2.imread(str(cut), cv2.IMREAD_COLOR)
    if suffix == ".jpg":  # the trap: OpenCV hands back a full-size, partly grey picture
        assert decoded is not None and decoded.shape == (120, 160, 3)
    with pytest.raises(InputError) as caught:
        read_image(cut)
    message = str(caught.value)
    assert str(cut) in message and ("cut short" in message or "incomplete" in message
                                    or "cannot decode" in message)


def test_jpeg_padding_after_the_end_marker_is_accepted():
    assert incomplete_reason(encoded(".jpg") + b"\x00" * 16) is None


def test_a_png_with_a_flipped_byte_is_refused_naming_the_chunk(tmp_path):
    data = bytearray(encoded(".png"))
    data[60] ^= 0x55                                   # inside the first IDAT's data
    path = tmp_path / "mask.png"
    path.write_bytes(bytes(data))
    reason = incomplete_reason(bytes(data))
    assert reason is not None and "CRC" in reason
    with pytest.raises(InputError, match="mask: cannot decode image: PNG corrupt"):
        read_mask(path)


def test_a_batch_skips_a_cut_image_and_measures_the_rest(tmp_path):
    dataset = tmp_path / "flight"
    shutil.copytree(SAMPLES, dataset)
    image = dataset / "images" / "000001.png"
    data = image.read_bytes()
    image.write_bytes(data[: int(len(data) * 0.6)])
    out = tmp_path / "out"
    result = runner.invoke(app, ["measure", str(dataset), "--out", str(out), "--no-tables"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.glob("*.json")) == ["000000.json", "000002.json",
                                                          "000003.json", "000004.json"]
    assert "000001.png: cannot decode image: PNG cut short" in result.output.replace("\n", " ")


def test_segment_lists_a_cut_jpeg_and_writes_the_others(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    data = encoded(".jpg")
    (folder / "a.jpg").write_bytes(data)
    (folder / "b.jpg").write_bytes(data[: len(data) // 2])
    out = tmp_path / "masks"
    result = runner.invoke(app, ["segment", str(folder), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "a.png").is_file() and not (out / "b.png").exists()
    summary = json.loads((out / "segment.json").read_text())
    assert "JPEG cut short" in json.dumps(summary)


def test_training_and_segmentation_need_no_clearance_stack():
    """Training, evaluation and `segment` read images through harborsight.images alone: a GPU
    machine without the geodesy and mesh libraries can train (the first H200 run stopped at a
    missing pymap3d when the readers lived in harborsight.pipeline)."""
    import subprocess
    import sys

    code = ("import sys, harborsight.training.loop, harborsight.training.dataset, "
            "harborsight.evaluation.segmentation, harborsight.perception.segment_images, "
            "harborsight.cli.training; "
            "print(sorted({'pymap3d', 'shapely', 'trimesh'} & set(sys.modules)))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True)
    assert result.stdout.strip() == "[]"


@pytest.mark.parametrize("orientation, refused", [(1, False), (0, False), (3, True), (6, True)])
def test_a_frame_stored_turned_is_refused_for_measuring_only(tmp_path, orientation, refused):
    """EXIF Orientation 2-8 says the picture is stored turned (OpenCV turns a JPEG back);
    0 is not defined and turns nothing. ``segment`` and training read it as decoded."""
    exif = Image.Exif()
    exif[0x0112] = orientation
    path = tmp_path / "frame.jpg"
    Image.fromarray(np.zeros((36, 64, 3), np.uint8)).save(path, exif=exif)
    assert read_image(path).shape[2] == 3
    if refused:
        with pytest.raises(InputError, match=rf"frame.jpg: Orientation: EXIF Orientation {orientation}"):
            read_image(path, camera_pixels=True)
    else:
        assert read_image(path, camera_pixels=True).shape == (36, 64, 3)



def test_a_whole_jpeg_with_bytes_after_its_end_is_accepted_and_a_cut_one_still_refused():
    """A phone's trailer or a motion photo's clip follows the End Of Image marker: the JPEG
    was refused as "cut short" (OpenCV decodes it as it is). Its segments are walked to the
    marker; a stream that ends before it is still cut short, with a trailer or without."""
    data = encoded(".jpg")
    trailer = b"MotionPhoto_Data" + bytes(range(256)) * 40
    assert incomplete_reason(data + trailer) is None
    assert incomplete_reason(data[: len(data) // 2]) is not None
    assert "cut short" in incomplete_reason(data[: len(data) - 40] + b"\xff\x00" * 3)


def test_a_float_tiff_is_left_to_opencv_and_a_giant_one_is_named_not_raised(tmp_path):
    """A 32-bit float TIFF, which Pillow cannot identify, was refused as "incomplete or
    corrupt" with an object's repr in the message; OpenCV reads it. A valid TIFF of more
    pixels than OpenCV decodes made Pillow raise its decompression-bomb error, which nothing
    caught: `segment` stopped, the images after it lost. It is listed with its size; the
    rest are segmented."""
    import struct

    assert cv2.imwrite(str(tmp_path / "float.tif"),
                       np.random.default_rng(0).random((50, 70, 3)).astype(np.float32))
    data = (tmp_path / "float.tif").read_bytes()
    assert incomplete_reason(data) is None
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape == (50, 70, 3)
    giant = tmp_path / "photos" / "b_giant.tif"
    giant.parent.mkdir()
    # a greyscale TIFF of 33000 x 33000 (one strip; its pixels are never read)
    entries = [(256, 4, 33000), (257, 4, 33000), (258, 3, 8), (259, 3, 1), (262, 3, 1),
               (273, 4, 8 + 2 + 12 * 8 + 4), (278, 4, 33000), (279, 4, 33000 * 33000)]
    giant.write_bytes(b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", len(entries))
                      + b"".join(struct.pack("<HHII", tag, kind, 1, value)
                                 for tag, kind, value in entries)
                      + struct.pack("<I", 0) + bytes(64))
    for name in ("a.jpg", "c.jpg"):
        (giant.parent / name).write_bytes(encoded(".jpg"))
    reason = incomplete_reason(giant.read_bytes())
    assert reason is not None and "33000x33000" in reason and "tiles" in reason
    out = tmp_path / "masks"
    result = runner.invoke(app, ["segment", str(giant.parent), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "a.png").is_file() and (out / "c.png").is_file()
    assert "33000x33000" in json.dumps(json.loads((out / "segment.json").read_text()))


@pytest.mark.parametrize("orientation", [3, 6, 8, 5])
def test_a_webp_is_read_turned_by_its_exif_orientation_as_a_jpeg_is(tmp_path, orientation):
    """OpenCV turns a JPEG, PNG or TIFF by its EXIF Orientation as it reads it, not a WebP;
    annotation tools (LabelMe, Ultralytics) show all of them turned, so a WebP's mask was
    imported 180 degrees off (or refused for its size). Read as Pillow turns it for show."""
    from PIL import ImageOps

    stored = Image.fromarray(picture()[:, :150])          # 150 x 120, not square
    exif = Image.Exif()
    exif[0x0112] = orientation
    path = tmp_path / "turned.webp"
    stored.save(path, format="WEBP", lossless=True, exif=exif)
    with Image.open(path) as opened:
        shown = np.asarray(ImageOps.exif_transpose(opened).convert("RGB"))[..., ::-1]
    assert np.array_equal(read_image(path), shown)


@pytest.mark.parametrize("bits", [10, 12, 16])
def test_a_16_bit_image_is_read_by_its_own_bit_depth(tmp_path, bits):
    """A camera's 10- or 12-bit samples stored in a 16-bit PNG or TIFF were divided by 256 by
    OpenCV's 8-bit decoding (0-15 for 12 bits: near black, and a model read 97 % of such a
    frame as water). They are scaled by the image's own depth: within a grey level of the
    8-bit original; a full 16-bit image as before."""
    original = cv2.imread(str(SAMPLES / "images" / "000000.png"))
    deep = (original.astype(np.uint32) * ((1 << bits) - 1) // 255).astype(np.uint16)
    for suffix in (".png", ".tif"):
        path = tmp_path / f"deep{bits}{suffix}"
        assert cv2.imwrite(str(path), deep)
        read = read_image(path)
        assert read.dtype == np.uint8 and read.shape == original.shape
        assert np.abs(read.astype(int) - original.astype(int)).max() <= 1
