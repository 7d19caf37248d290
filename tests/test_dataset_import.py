"""harborsight dataset import: COCO, LabelMe, CVAT and YOLO annotations become the dataset layout
(pixels checked against independent rasterisations), bad input costs only its frame, and the
result trains, evaluates and exports."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from matplotlib.path import Path as MplPath
from pycocotools import mask as coco_mask
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.datasets import (
    Box,
    ImageBoxes,
    ImportOptions,
    import_dataset,
    parse_class_map,
    read_annotations,
    read_class_names,
    read_yolo_boxes,
)
from harborsight.datasets.annotations import Polygons
from harborsight.errors import InputError
from harborsight.training.dataset import list_frames, read_labelled_frame

runner = CliRunner()
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "aerial-maritime-drone"
H, W = 40, 60


# ------------------------------------------------------------------------ helpers


def write_image(path: Path, h: int = H, w: int = W, seed: int = 0) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    image = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), image)
    return path


def centre_rule(points, h: int = H, w: int = W) -> np.ndarray:
    """Pixels whose centre lies inside the polygon (matplotlib, not pycocotools)."""
    yy, xx = np.mgrid[0:h, 0:w]
    centres = np.column_stack([xx.ravel() + 0.5, yy.ravel() + 0.5])
    return MplPath(np.asarray(points, float)).contains_points(centres).reshape(h, w)


def coco_polygon(points, h: int = H, w: int = W) -> np.ndarray:
    """pycocotools' own rasterisation of a polygon given as [(x, y), ...]."""
    flat = np.asarray(points, float).ravel().tolist()
    return coco_mask.decode(coco_mask.frPyObjects([flat], h, w)[0]).astype(bool)


def boundary_band(points, h: int = H, w: int = W, px: float = 1.0) -> np.ndarray:
    """Pixels whose centre is within ``px`` of the polygon's outline."""
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    pts = np.asarray(points, float)
    dist = np.full((h, w), np.inf)
    for a, b in zip(pts, np.roll(pts, -1, axis=0), strict=True):
        d = b - a
        t = np.clip(((xx - a[0]) * d[0] + (yy - a[1]) * d[1]) / (d @ d), 0, 1)
        dist = np.minimum(dist, np.hypot(xx - a[0] - t * d[0], yy - a[1] - t * d[1]))
    return dist <= px


def uncompressed_rle(mask: np.ndarray) -> dict:
    """COCO uncompressed RLE written here (column-major runs, zeros first)."""
    flat = mask.T.ravel().astype(np.uint8)
    edges = np.flatnonzero(np.diff(flat)) + 1
    runs = np.diff(np.concatenate([[0], edges, [flat.size]])).tolist()
    if flat[0]:
        runs = [0, *runs]
    return {"size": list(mask.shape), "counts": runs}


def cvat_rle(patch: np.ndarray) -> str:
    """CVAT's mask runs written here (row-major over the patch, zeros first)."""
    flat = patch.ravel().astype(np.uint8)
    edges = np.flatnonzero(np.diff(flat)) + 1
    runs = np.diff(np.concatenate([[0], edges, [flat.size]])).tolist()
    if flat[0]:
        runs = [0, *runs]
    return ", ".join(str(r) for r in runs)


def labels_of(dataset: Path, stem: str) -> np.ndarray:
    labels = cv2.imread(str(dataset / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
    assert labels is not None and labels.dtype == np.uint8 and labels.ndim == 2
    return labels


def invoke(*args: str):
    return runner.invoke(app, ["dataset", "import", *map(str, args), "--no-progress"])


def coco_doc(images: list[tuple[int, str]], annotations: list[dict], categories: list[str],
             h: int = H, w: int = W) -> dict:
    return {"images": [{"id": i, "file_name": name, "width": w, "height": h} for i, name in images],
            "annotations": [{"id": k + 1, "iscrowd": 0, **a} for k, a in enumerate(annotations)],
            "categories": [{"id": k + 1, "name": n} for k, n in enumerate(categories)]}


def write_json(path: Path, doc) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


# ------------------------------------------------------------------------ class names


def test_parse_class_map_accepts_names_and_numbers_and_refuses_the_rest():
    assert parse_class_map(["Boat=ship", "dock = Obstacle", "boat lift=2", "wake=0", "blur=255",
                            "boat=1"]) == {"boat": 1, "dock": 2, "boat lift": 2, "wake": 0, "blur": 255}
    for bad, message in [("boat", "expected NAME=CLASS"), ("=ship", "expected NAME=CLASS"),
                         ("boat=vessel", "unknown class 'vessel'"), ("boat=3", "unknown class '3'")]:
        with pytest.raises(InputError, match=message) as info:
            parse_class_map([bad])
        assert info.value.field == "--map"
    with pytest.raises(InputError, match="'BOAT' is mapped to both ship and obstacle"):
        parse_class_map(["boat=ship", "BOAT=obstacle"])


def test_read_class_names_from_yaml_list_yaml_map_and_txt(tmp_path):
    (tmp_path / "a.yaml").write_text("nc: 2\nnames: ['boat', 'dock']\n")
    (tmp_path / "b.yaml").write_text("names:\n  1: dock\n  0: boat\n")
    (tmp_path / "classes.txt").write_text("boat\ndock\n\n")
    assert read_class_names(tmp_path / "a.yaml") == read_class_names(tmp_path / "b.yaml") == [
        "boat", "dock"] == read_class_names(tmp_path / "classes.txt")
    (tmp_path / "c.yaml").write_text("names:\n  0: boat\n  2: dock\n")
    with pytest.raises(InputError, match=r"c.yaml: names: class ids \[0, 2\] do not run 0..1"):
        read_class_names(tmp_path / "c.yaml")
    (tmp_path / "d.yaml").write_text("nc: 2\n")
    with pytest.raises(InputError, match=r"d\.yaml: names"):
        read_class_names(tmp_path / "d.yaml")


# ------------------------------------------------------------------------ formats


L_SHAPE = [(5, 4), (30, 4), (30, 12), (14, 12), (14, 30), (5, 30)]     # whole-pixel corners
TRIANGLE = [(33.3, 5.2), (57.6, 18.9), (36.1, 35.7)]


def test_coco_polygons_and_rles_become_the_expected_pixels(tmp_path):
    write_image(tmp_path / "coco" / "images" / "a.png")
    disk = np.hypot(*np.mgrid[0:H, 0:W][::-1] - np.array([45, 28])[:, None, None]) < 8
    crowd = np.zeros((H, W), bool)
    crowd[2:9, 40:58] = True
    annotations = [
        {"image_id": 1, "category_id": 1, "segmentation": [np.ravel(L_SHAPE).tolist()]},
        {"image_id": 1, "category_id": 2, "segmentation": [np.ravel(TRIANGLE).tolist()]},
        {"image_id": 1, "category_id": 3, "segmentation": uncompressed_rle(disk)},   # over the triangle
        {"image_id": 1, "category_id": 4, "iscrowd": 1,
         "segmentation": {**coco_mask.encode(np.asfortranarray(crowd.astype(np.uint8))),
                          "counts": coco_mask.encode(np.asfortranarray(crowd.astype(np.uint8)))[
                              "counts"].decode()}},
    ]
    ann = write_json(tmp_path / "coco" / "instances.json",
                     coco_doc([(1, "a.png")], annotations, ["Boat", "dock", "lift", "spray"]))
    result = invoke(ann, "--format", "coco", "--out", tmp_path / "ds", "--map", "boat=ship",
                    "--map", "DOCK=obstacle", "--map", "lift=2", "--map", "spray=ignore")
    assert result.exit_code == 0, result.output
    got = labels_of(tmp_path / "ds", "a")
    # in file order: the L shape (ship), the triangle (obstacle), the disk over the triangle
    # (obstacle), the crowd RLE over both (ignore); L shape and RLEs exact, from slices and the
    # masks above; the triangle by its pixel centres, up to a one-pixel band along its outline
    expected = np.zeros((H, W), np.uint8)
    expected[4:12, 5:30] = 1
    expected[12:30, 5:14] = 1
    expected[centre_rule(TRIANGLE)] = 2
    expected[disk] = 2
    expected[crowd] = 255
    differ = got != expected
    assert not (differ & ~(boundary_band(TRIANGLE) & ~disk & ~crowd)).any() and differ.sum() < 10
    assert np.array_equal(got == 1, expected == 1) and np.array_equal(got == 255, crowd)
    assert (got[disk & ~crowd] == 2).all() and (got[crowd & centre_rule(TRIANGLE)] == 255).all()
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["schema"] == "harborsight.dataset/1" and meta["split"] == {"a": "train"}
    assert meta["class_map"] == {"boat": "ship", "dock": "obstacle", "lift": "obstacle",
                                 "spray": "ignore"}
    assert meta["classes"] == {"0": "water", "1": "ship", "2": "obstacle"}
    assert meta["ignore_index"] == 255 and meta["frames_without_pose"] is True
    assert meta["source"]["format"] == "coco" and meta["skipped"] == []
    assert (tmp_path / "ds" / "images" / "a.png").read_bytes() == (
        tmp_path / "coco" / "images" / "a.png").read_bytes()
    (record,) = list_frames([tmp_path / "ds"])
    image, labels = read_labelled_frame(record)
    assert image.shape == (H, W, 3) and np.array_equal(labels, got)


def test_coco_triangle_matches_pycocotools_and_the_centre_rule(tmp_path):
    write_image(tmp_path / "a.png")
    ann = write_json(tmp_path / "c.json", coco_doc([(7, "a.png")], [
        {"image_id": 7, "category_id": 1, "segmentation": [np.ravel(TRIANGLE).tolist()]}], ["ship"]))
    assert invoke(ann, "-f", "coco", "--out", tmp_path / "ds").exit_code == 0
    got = labels_of(tmp_path / "ds", "a") == 1
    assert np.array_equal(got, coco_polygon(TRIANGLE))
    differ = got != centre_rule(TRIANGLE)
    assert not (differ & ~boundary_band(TRIANGLE)).any() and differ.sum() < 10


def test_polygons_paint_what_pycocotools_decodes_even_past_the_edge():
    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(3, 9))
        ring = np.column_stack([rng.uniform(-8, W + 8, n), rng.uniform(-8, H + 8, n)])
        flat = ring.ravel().tolist()
        expected = coco_mask.decode(coco_mask.frPyObjects([flat], H, W)[0]).astype(bool)
        assert np.array_equal(Polygons((ring,)).rasterise(H, W), expected)


def test_broken_rles_cost_their_frame_before_pycocotools_sees_them(tmp_path):
    write_image(tmp_path / "a.png")
    good = coco_mask.encode(np.asfortranarray(np.ones((H, W), np.uint8)))["counts"].decode()
    segs = [{"size": [H, W], "counts": good[:-1] + "#"}, {"size": [H, W], "counts": [5, -1, H * W - 4]},
            {"size": [H, W], "counts": [5, 10]}, {"size": [H], "counts": [H * W]}]
    ann = write_json(tmp_path / "c.json", coco_doc([(1, "a.png")], [
        {"image_id": 1, "category_id": 1, "segmentation": seg} for seg in segs], ["ship"]))
    (frame,) = read_annotations("coco", [ann]).frames
    assert frame.shapes == []
    reasons = [(p.field, p.reason) for p in frame.problems]
    assert reasons[0][0] == "annotations[0].segmentation" and "not a COCO compressed RLE" in reasons[0][1]
    assert "non-negative whole numbers" in reasons[1][1]
    assert "the runs cover 15 pixels, size 60x40 has 2400" in reasons[2][1]
    assert "size: expected [height, width]" in reasons[3][1]


def labelme_doc(image: str, shapes: list[dict], h: int = H, w: int = W) -> dict:
    return {"version": "5.4.1", "flags": {}, "shapes": [
        {"group_id": None, "flags": {}, "description": "", **s} for s in shapes],
        "imagePath": image, "imageData": None, "imageHeight": h, "imageWidth": w}


def png_b64(mask: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    assert ok
    return base64.b64encode(buf.tobytes()).decode()


def test_labelme_shapes_become_the_expected_pixels(tmp_path):
    write_image(tmp_path / "pics" / "harbour_1.jpg")
    patch = np.zeros((6, 9), bool)
    patch[1:5, 2:8] = True
    patch[3, 4] = False
    shapes = [
        {"label": "pier", "shape_type": "rectangle", "points": [[50.6, 30.2], [40.3, 20.7]]},
        {"label": "boat", "shape_type": "polygon", "points": [list(p) for p in TRIANGLE]},
        {"label": "Buoy", "shape_type": "circle", "points": [[12.2, 20.4], [12.2, 26.9]]},
        {"label": "boat", "shape_type": "mask", "points": [[3, 31], [11, 36]], "mask": png_b64(patch)},
        {"label": "rope", "shape_type": "linestrip", "points": [[1, 1], [5, 5], [9, 1]]},
    ]
    write_json(tmp_path / "json" / "harbour_1.json", labelme_doc("../pics/harbour_1.jpg", shapes))
    result = invoke(tmp_path / "json", "--format", "labelme", "--out", tmp_path / "ds",
                    "--map", "pier=obstacle", "--map", "boat=ship", "--map", "buoy=obstacle")
    assert result.exit_code == 0, result.output
    got = labels_of(tmp_path / "ds", "harbour_1")
    expected = np.zeros((H, W), np.uint8)
    expected[21:30, 40:51] = 2                      # centres in [40.3, 50.6) x [20.7, 30.2)
    expected[coco_polygon(TRIANGLE)] = 1            # over the rectangle
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    expected[np.hypot(xx - 12.2, yy - 20.4) <= 6.5] = 2
    expected[31:37, 3:12][patch] = 1
    assert np.array_equal(got, expected)
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert [w["field"] for w in meta["warnings"]] == ["shapes[4].shape_type"]
    assert (tmp_path / "ds" / "images" / "harbour_1.jpg").read_bytes() == (
        tmp_path / "pics" / "harbour_1.jpg").read_bytes()


def test_labelme_embedded_image_data_is_used_when_the_file_is_missing(tmp_path):
    image = write_image(tmp_path / "x.png")
    doc = labelme_doc("gone/x.png", [{"label": "ship", "shape_type": "polygon", "points": L_SHAPE}])
    doc["imageData"] = base64.b64encode(image.read_bytes()).decode()
    write_json(tmp_path / "ann" / "x.json", doc)
    assert invoke(tmp_path / "ann", "-f", "labelme", "--out", tmp_path / "ds").exit_code == 0
    assert (tmp_path / "ds" / "images" / "x.png").read_bytes() == image.read_bytes()
    assert (labels_of(tmp_path / "ds", "x") == 1).sum() == 25 * 8 + 9 * 18


def cvat_xml(images: list[tuple[str, str]], h: int = H, w: int = W) -> str:
    body = "".join(f'<image id="{k}" name="{name}" width="{w}" height="{h}">{shapes}</image>'
                   for k, (name, shapes) in enumerate(images))
    return f'<?xml version="1.0" encoding="utf-8"?><annotations><version>1.1</version>{body}</annotations>'


def test_cvat_shapes_and_z_order_become_the_expected_pixels(tmp_path):
    write_image(tmp_path / "export" / "images" / "f1.png")
    patch = np.zeros((7, 10), bool)
    patch[2:6, 1:9] = True
    patch[0, 0] = True
    points = ";".join(f"{x},{y}" for x, y in TRIANGLE)
    shapes = (
        '<box label="jetty" xtl="20" ytl="10" xbr="50" ybr="30" z_order="1" occluded="0"></box>'
        f'<polygon label="boat" points="{points}" z_order="0"></polygon>'     # under the box
        f'<mask label="boat" rle="{cvat_rle(patch)}" left="2" top="30" width="10" height="7" z_order="0"/>'
        '<box label="wake" xtl="0" ytl="0" xbr="8" ybr="6" z_order="2"/>'
        '<polyline label="rope" points="1,1;5,5"/><tag label="sunny"/>')
    xml = tmp_path / "export" / "annotations.xml"
    xml.write_text(cvat_xml([("f1.png", shapes)]))
    result = invoke(xml, "--format", "cvat", "--out", tmp_path / "ds", "--map", "jetty=obstacle",
                    "--map", "boat=ship", "--map", "wake=ignore")
    assert result.exit_code == 0, result.output
    got = labels_of(tmp_path / "ds", "f1")
    expected = np.zeros((H, W), np.uint8)
    expected[coco_polygon(TRIANGLE)] = 1
    expected[30:37, 2:12][patch] = 1
    expected[10:30, 20:50] = 2
    expected[0:6, 0:8] = 255
    assert np.array_equal(got, expected)
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert [w["field"] for w in meta["warnings"]] == ["image[0][name=f1.png].polyline[0]"]


def test_cvat_rotated_box_and_ellipse(tmp_path):
    """Rotations turn clockwise on the picture about the shape's centre (CVAT's convention)."""
    write_image(tmp_path / "g.png")
    xml = tmp_path / "a.xml"
    xml.write_text(cvat_xml([("g.png", '<box label="ship" xtl="10" ytl="15" xbr="40" ybr="25" '
                              'rotation="30"/><ellipse label="obstacle" cx="48" cy="12" rx="9" '
                              'ry="4" rotation="30"/>')]))
    assert invoke(xml, "-f", "cvat", "--out", tmp_path / "ds").exit_code == 0
    got = labels_of(tmp_path / "ds", "g")
    a = np.deg2rad(30)
    axis = np.array([np.cos(a), np.sin(a)])          # x turned 30 degrees toward +y (down)
    normal = np.array([-np.sin(a), np.cos(a)])
    corners = [(25, 20) + sx * 15 * axis + sy * 5 * normal for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    c = np.sqrt(9**2 - 4**2)                          # the ellipse's foci on its turned long axis
    foci = [np.array([48, 12]) + s * c * axis for s in (-1, 1)]
    ellipse = sum(np.hypot(xx - f[0], yy - f[1]) for f in foci) <= 2 * 9
    expected = np.zeros((H, W), np.uint8)
    expected[centre_rule(corners)] = 1
    expected[ellipse] = 2
    differ = got != expected
    assert not (differ & ~(boundary_band(corners) & ~ellipse)).any() and differ.sum() < 12
    assert np.array_equal(got == 2, ellipse)


def test_yolo_polygons_become_the_expected_pixels(tmp_path):
    write_image(tmp_path / "images" / "train" / "p1.png")
    write_image(tmp_path / "images" / "train" / "p2.jpeg", seed=1)
    (tmp_path / "data.yaml").write_text("names:\n  0: Boat\n  1: dock\n")
    line = " ".join(f"{x / W:.6f} {y / H:.6f}" for x, y in TRIANGLE)
    l_line = " ".join(f"{x / W:.6f} {y / H:.6f}" for x, y in L_SHAPE)
    (tmp_path / "labels" / "train").mkdir(parents=True)
    (tmp_path / "labels" / "train" / "p1.txt").write_text(f"1 {l_line}\n0 {line}\n")
    (tmp_path / "labels" / "train" / "p2.txt").write_text(f"0 {l_line}\n")
    result = invoke(tmp_path / "labels", "--format", "yolo", "--out", tmp_path / "ds",
                    "--map", "boat=ship", "--map", "dock=obstacle")
    assert result.exit_code == 0, result.output
    expected = np.zeros((H, W), np.uint8)
    expected[4:12, 5:30] = 2
    expected[12:30, 5:14] = 2
    as_written = [(float(f"{x / W:.6f}") * W, float(f"{y / H:.6f}") * H) for x, y in TRIANGLE]
    expected[coco_polygon(as_written)] = 1
    assert np.array_equal(labels_of(tmp_path / "ds", "p1"), expected)
    assert np.array_equal(labels_of(tmp_path / "ds", "p2"), (expected == 2).astype(np.uint8))
    assert sorted(p.name for p in (tmp_path / "ds" / "images").iterdir()) == ["p1.png", "p2.jpeg"]


def test_yolo_boxes_are_not_imported_as_masks(tmp_path):
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "a.txt").write_text("0 0.5 0.5 0.2 0.2\n")
    result = invoke(tmp_path / "labels", "--format", "yolo-boxes", "--out", tmp_path / "ds")
    assert result.exit_code == 2 and "harborsight dataset label-from-boxes" in result.output
    assert not (tmp_path / "ds").exists()
    # and a box line inside a segmentation file costs its frame
    write_image(tmp_path / "images" / "a.png")
    (tmp_path / "labels" / "classes.txt").write_text("ship\n")
    result = invoke(tmp_path / "labels", "--format", "yolo-seg", "--out", tmp_path / "ds")
    assert result.exit_code == 1 and "a.txt: line 1: a box (class cx cy w h)" in result.output


def test_read_yolo_boxes_in_pixels_clipped_with_skipped_files(tmp_path):
    write_image(tmp_path / "img" / "a.jpg")
    write_image(tmp_path / "img" / "b.png")
    (tmp_path / "img" / "c.png").write_bytes(b"not a picture")
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "a.txt").write_text("0 0.5 0.25 0.2 0.1\n2 0.95 0.5 0.2 0.5\n1 1.5 0.5 0.2 0.2\n")
    (lab / "b.txt").write_text("")
    (lab / "c.txt").write_text("0 0.5 0.5 0.1 0.1\n")
    (lab / "d.txt").write_text("0 0.5 0.5 0.1 0.1\n")
    (lab / "e.txt").write_text("0 0.5 0.5 0.1\n")
    names = ["Boat", "car", "dock"]
    images, skipped = read_yolo_boxes(lab, tmp_path / "img", names,
                                      parse_class_map(["boat=ship", "car=obstacle", "dock=obstacle"]))
    assert [i.image_path.name for i in images] == ["a.jpg", "b.png"]
    a = images[0]
    assert isinstance(a, ImageBoxes) and (a.width, a.height) == (W, H)
    assert a.boxes == (Box("Boat", 1, 24.0, 8.0, 36.0, 12.0), Box("dock", 2, 51.0, 10.0, 60.0, 30.0))
    assert images[1].boxes == ()
    assert sorted(Path(p).name for p, _ in skipped) == ["c.txt", "d.txt", "e.txt"]
    reasons = dict((Path(p).name, r) for p, r in skipped)
    assert "cannot decode image" in reasons["c.txt"] and "no image d.*" in reasons["d.txt"]
    assert "e.txt: line 1: expected class cx cy w h" in reasons["e.txt"]
    with pytest.raises(InputError, match=r"2 class name\(s\) with no harborsight class: 'Boat' "
                                         r"\(4 shapes, first in .*a.txt\), 'dock'"):
        read_yolo_boxes(lab, tmp_path / "img", names, parse_class_map(["car=obstacle"]))


@pytest.mark.skipif(not (REAL / "boxes").is_dir(), reason="shared real data not present")
def test_read_yolo_boxes_of_the_real_drone_photos():
    names = read_class_names(REAL / "classes.yaml")
    assert names == ["boat", "car", "dock", "jetski", "lift"]
    mapping = parse_class_map(["boat=ship", "jetski=ship", "car=obstacle", "dock=obstacle",
                               "lift=obstacle"])
    images, skipped = read_yolo_boxes(REAL / "boxes", REAL / "photos", names, mapping)
    assert skipped == [] and len(images) == len(list((REAL / "boxes").glob("*.txt"))) == 42
    lines = [line for p in (REAL / "boxes").glob("*.txt") for line in p.read_text().splitlines()
             if line.strip()]
    assert sum(len(i.boxes) for i in images) == len(lines) > 500   # every box lies in its photo
    for item in images:
        assert (item.width, item.height) == (2048, 1536) and item.image_path.suffix == ".jpg"
        for box in item.boxes:
            assert 0 <= box.x0 < box.x1 <= 2048 and 0 <= box.y0 < box.y1 <= 1536
            assert box.class_id == (1 if box.label in ("boat", "jetski") else 2)
    first = next(i for i in images if i.image_path.stem == "DJI_0258")
    cls, cx, cy, w, h = (float(v) for v in (REAL / "boxes" / "DJI_0258.txt").read_text().split()[:5])
    assert first.boxes[0].label == names[int(cls)]
    assert first.boxes[0].x0 == pytest.approx((cx - w / 2) * 2048)
    assert first.boxes[0].y1 == pytest.approx((cy + h / 2) * 1536)


# ------------------------------------------------------------------------ mapping and bad input


def test_unknown_class_names_are_all_listed_before_anything_is_written(tmp_path):
    write_image(tmp_path / "a.png")
    write_image(tmp_path / "b.png")
    ann = write_json(tmp_path / "c.json", coco_doc([(1, "a.png"), (2, "b.png")], [
        {"image_id": 1, "category_id": 1, "segmentation": [np.ravel(L_SHAPE).tolist()]},
        {"image_id": 1, "category_id": 2, "segmentation": [np.ravel(TRIANGLE).tolist()]},
        {"image_id": 2, "category_id": 3, "segmentation": [np.ravel(TRIANGLE).tolist()]},
        {"image_id": 2, "category_id": 4, "segmentation": [np.ravel(TRIANGLE).tolist()]},
    ], ["boat", "Buoy", "tree", "Water"]))
    result = invoke(ann, "-f", "coco", "--out", tmp_path / "ds", "--map", "BOAT=ship")
    assert result.exit_code == 2
    out = " ".join(result.output.split())
    assert "c.json: label: 2 class name(s) with no harborsight class:" in out
    assert "'Buoy' (1 shape, first in" in out and "'tree' (1 shape" in out and "'boat'" not in out
    assert "--map NAME=water|ship|obstacle|ignore" in out and not (tmp_path / "ds").exists()
    result = invoke(ann, "-f", "coco", "--out", tmp_path / "ds", "--map", "boat=ship", "--map",
                    "buoy=obstacle", "--map", "tree=bush")
    assert result.exit_code == 2 and "--map: 'tree=bush': unknown class 'bush'" in result.output


def test_bad_frames_are_skipped_and_named_while_the_others_are_imported(tmp_path):
    src = tmp_path / "src"
    for name in ("good", "outside", "small", "rlesize"):
        write_image(src / f"{name}.png")
    write_image(src / "big.png", 50, 60)
    (src / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a picture")
    poly = [np.ravel(L_SHAPE).tolist()]
    outside = [(-10, -5), (20, -5), (20, 10), (-10, 10)]
    images = [(1, "good.png"), (2, "broken.png"), (3, "missing.png"), (4, "outside.png"),
              (5, "big.png"), (6, "rlesize.png"), (7, "unlabelled.png")]
    doc = coco_doc(images, [
        {"image_id": i, "category_id": 1, "segmentation": poly} for i in (1, 2, 3, 5)] + [
        {"image_id": 4, "category_id": 1, "segmentation": [np.ravel(outside).tolist()]},
        {"image_id": 6, "category_id": 1, "segmentation": uncompressed_rle(np.ones((H, W + 1), bool))},
    ], ["ship"])
    doc["images"][5].pop("width"), doc["images"][5].pop("height")   # RLE size vs the image itself
    write_image(src / "unlabelled.png")
    ann = write_json(src / "instances.json", doc)
    result = invoke(ann, "-f", "coco", "--out", tmp_path / "ds")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["split"] == {"good": "train", "outside": "train"}
    skipped = {(s["field"], Path(s["file"]).name): s["reason"] for s in meta["skipped"]}
    assert set(skipped) == {("images[1].image", "instances.json"), ("images[2].file_name", "instances.json"),
                            ("images[4].width/height", "instances.json"),
                            ("annotations[5].segmentation", "instances.json"),
                            ("images[6]", "instances.json")}
    assert "cannot decode image" in skipped[("images[1].image", "instances.json")]
    assert "image file not found: missing.png" in skipped[("images[2].file_name", "instances.json")]
    assert "60x40 but the image big.png is 60x50 (a mask of another size)" in skipped[
        ("images[4].width/height", "instances.json")]
    assert "RLE of 61x40" in skipped[("annotations[5].segmentation", "instances.json")]
    assert "no annotated regions" in skipped[("images[6]", "instances.json")]
    for line in ("instances.json: images[1].image: cannot decode image",
                 "instances.json: images[2].file_name: image file not found: missing.png",
                 "instances.json: annotations[4].segmentation: 'ship' reaches outside the 60x40 image"):
        assert line in result.output
    (warning,) = meta["warnings"]
    assert warning["field"] == "annotations[4].segmentation" and "cut off" in warning["reason"]
    clipped = np.zeros((H, W), np.uint8)
    clipped[0:10, 0:20] = 1
    assert np.array_equal(labels_of(tmp_path / "ds", "outside"), clipped)
    assert sorted(p.name for p in (tmp_path / "ds" / "images").iterdir()) == ["good.png", "outside.png"]
    assert sorted(p.name for p in (tmp_path / "ds" / "labels").iterdir()) == ["good.png", "outside.png"]



def test_an_image_name_too_long_to_look_up_is_a_missing_image(tmp_path):
    """A file_name of 3,000 characters made pathlib raise (ENAMETOOLONG) instead of saying
    the image is missing; the other frame is still imported."""
    src = tmp_path / "src"
    write_image(src / "good.png")
    poly = [np.ravel(L_SHAPE).tolist()]
    doc = coco_doc([(1, "good.png"), (2, "x" * 3000 + ".png")],
                   [{"image_id": i, "category_id": 1, "segmentation": poly} for i in (1, 2)], ["ship"])
    result = invoke(write_json(src / "instances.json", doc), "-f", "coco", "--out", tmp_path / "ds")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["split"] == {"good": "train"}
    (skipped,) = meta["skipped"]
    assert skipped["field"] == "images[1].file_name" and "image file not found" in skipped["reason"]

def test_labelme_size_mismatch_and_empty_files_are_reported(tmp_path):
    write_image(tmp_path / "a.png")
    write_image(tmp_path / "b.png", 30, 60)
    shape = [{"label": "ship", "shape_type": "polygon", "points": L_SHAPE}]
    write_json(tmp_path / "a.json", labelme_doc("a.png", shape))
    write_json(tmp_path / "b.json", labelme_doc("b.png", shape))           # says 60x40, is 60x30
    (tmp_path / "c.json").write_bytes(b"")
    write_json(tmp_path / "d.json", labelme_doc("d.png", shape))           # no d.png
    result = invoke(tmp_path, "-f", "labelme", "--out", tmp_path / "ds", "--keep-unlabelled")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert list(meta["split"]) == ["a"]
    skipped = {Path(s["file"]).name: (s["field"], s["reason"]) for s in meta["skipped"]}
    assert skipped["b.json"] == ("imageWidth/imageHeight", "60x40 but the image b.png is 60x30 "
                                 "(a mask of another size)")
    assert skipped["c.json"] == (None, "empty annotation file (0 bytes)")
    assert skipped["d.json"][0] == "imagePath" and "image file not found: d.png" in skipped["d.json"][1]


def test_empty_annotation_files_import_nothing_and_exit_1(tmp_path):
    empty = tmp_path / "empty.json"
    empty.write_bytes(b"")
    result = invoke(empty, "-f", "coco", "--out", tmp_path / "ds")
    assert result.exit_code == 1 and "empty.json: empty annotation file (0 bytes)" in result.output
    assert not (tmp_path / "ds").exists()
    no_images = write_json(tmp_path / "none.json", {"images": [], "annotations": [], "categories": []})
    result = invoke(no_images, "-f", "coco", "--out", tmp_path / "ds")
    assert result.exit_code == 1 and "none.json: images: no images" in result.output
    xml = tmp_path / "a.xml"
    xml.write_text(cvat_xml([]))
    result = invoke(xml, "-f", "cvat", "--out", tmp_path / "ds")
    assert result.exit_code == 1 and "a.xml: image: no <image> elements" in result.output
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "classes.txt").write_text("ship\n")
    (tmp_path / "labels" / "x.txt").write_bytes(b"")
    write_image(tmp_path / "images" / "x.png")
    result = invoke(tmp_path / "labels", "-f", "yolo-seg", "--out", tmp_path / "ds")
    assert result.exit_code == 1 and "x.txt: empty annotation file" in result.output
    result = invoke(tmp_path / "labels", "-f", "yolo-seg", "--out", tmp_path / "ds", "--keep-unlabelled",
                    "--background", "ignore")
    assert result.exit_code == 0 and (labels_of(tmp_path / "ds", "x") == 255).all()


def test_two_images_with_one_stem_are_an_error_naming_both(tmp_path):
    write_image(tmp_path / "a" / "f.png")
    write_image(tmp_path / "b" / "f.jpg")
    seg = [np.ravel(L_SHAPE).tolist()]
    ann = write_json(tmp_path / "c.json", coco_doc([(1, "a/f.png"), (2, "b/f.jpg")], [
        {"image_id": i, "category_id": 1, "segmentation": seg} for i in (1, 2)], ["ship"]))
    result = invoke(ann, "-f", "coco", "--out", tmp_path / "ds")
    out = " ".join(result.output.split())
    assert result.exit_code == 2 and "a/f.png and" in out and "b/f.jpg have one stem 'f'" in out
    assert not (tmp_path / "ds").exists()


def frames_dataset(root: Path, n: int, h: int = 64, w: int = 96, prefix: str = "f") -> Path:
    """``n`` LabelMe frames whose ship and obstacle follow the picture (bright ship, dark dock)."""
    rng = np.random.default_rng(n)
    for k in range(n):
        image = np.full((h, w, 3), (120, 80, 30), np.uint8)
        x = int(rng.integers(10, w - 40))
        image[10:30, x:x + 30] = 230
        image[h - 16:h, :] = 40
        path = root / f"{prefix}{k}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), image)
        write_json(root / f"{prefix}{k}.json", labelme_doc(path.name, [
            {"label": "boat", "shape_type": "rectangle", "points": [[x, 10], [x + 30, 30]]},
            {"label": "quay", "shape_type": "rectangle", "points": [[0, h - 16], [w, h]]}], h, w))
    return root


def test_split_file_append_max_side_and_tiff(tmp_path):
    src = frames_dataset(tmp_path / "src", 3)
    maps = ["--map", "boat=ship", "--map", "quay=obstacle"]
    split_csv = tmp_path / "splits.csv"
    split_csv.write_text("stem,split\nf0,train\nf1,val\n")
    result = invoke(src, "-f", "labelme", "--out", tmp_path / "ds", *maps, "--split-file", split_csv)
    assert result.exit_code == 2 and "splits.csv: stem: 1 imported frame(s) not listed: f2" in result.output
    split_csv.write_text("stem,split\nf0,train\nf1,val\nf2,test\nunused,val\n")
    result = invoke(src, "-f", "labelme", "--out", tmp_path / "ds", *maps, "--split-file", split_csv,
                    "--max-side", "48")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["split"] == {"f0": "train", "f1": "val", "f2": "test"}
    image = cv2.imread(str(tmp_path / "ds" / "images" / "f0.png"))
    labels = labels_of(tmp_path / "ds", "f0")
    assert image.shape == (32, 48, 3) and labels.shape == (32, 48)
    assert set(np.unique(labels)) == {0, 1, 2} and (labels[-8:] == 2).all()
    # not empty: refused without --append; with it, a stem already there is refused
    result = invoke(src, "-f", "labelme", "--out", tmp_path / "ds", *maps)
    assert result.exit_code == 2 and "not empty" in result.output
    result = invoke(src, "-f", "labelme", "--out", tmp_path / "ds", *maps, "--append")
    assert result.exit_code == 2 and "3 frame(s) already in the dataset: f0, f1, f2" in result.output
    more = frames_dataset(tmp_path / "more", 1, prefix="g")
    tif = cv2.imread(str(more / "g0.png"))
    assert cv2.imwrite(str(more / "g0.TIF"), tif)
    (more / "g0.png").unlink()
    doc = json.loads((more / "g0.json").read_text())
    doc["imagePath"] = "g0.TIF"
    write_json(more / "g0.json", doc)
    result = invoke(more, "-f", "labelme", "--out", tmp_path / "ds", *maps, "--append", "--split", "val")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["split"] == {"f0": "train", "f1": "val", "f2": "test", "g0": "val"}
    assert len(meta["imports"]) == 2 and meta["imports"][1]["frames"] == {"val": 1}
    assert np.array_equal(cv2.imread(str(tmp_path / "ds" / "images" / "g0.png")), tif)
    assert len(list_frames([tmp_path / "ds"], ["val"])) == 2


def test_library_import_without_the_cli(tmp_path):
    src = frames_dataset(tmp_path / "src", 2)
    seen = []
    result = import_dataset(ImportOptions("labelme", [src], tmp_path / "ds",
                                          class_map=parse_class_map(["boat=ship", "quay=obstacle"]),
                                          split="val"),
                            on_frame=lambda stem, problem: seen.append((stem, problem)))
    assert seen == [("f0", None), ("f1", None)] and result.frames_per_split() == {"val": 2}
    fractions = result.pixel_fractions()
    assert fractions["ship"] == pytest.approx(2 * 20 * 30 / (2 * 64 * 96))
    assert fractions["obstacle"] == pytest.approx(16 / 64) and fractions["ignore"] == 0


# ------------------------------------------------------------------------ train / evaluate / export


def test_an_imported_dataset_trains_evaluates_and_exports(tmp_path):
    src = frames_dataset(tmp_path / "src", 4)
    (tmp_path / "splits.csv").write_text("f0,train\nf1,train\nf2,val\nf3,test\n")
    result = invoke(src, "-f", "labelme", "--out", tmp_path / "ds", "--map", "boat=ship", "--map",
                    "quay=obstacle", "--split-file", tmp_path / "splits.csv")
    assert result.exit_code == 0, result.output
    assert not (tmp_path / "ds" / "frames").exists()
    run = tmp_path / "run"
    result = runner.invoke(app, ["train", "--out", str(run), "--model", "ddrnet23_slim", "--data",
                                 str(tmp_path / "ds"), "--iterations", "2", "--batch-size", "2",
                                 "--crop", "64", "--val-every", "2", "--checkpoint-every", "2",
                                 "--workers", "0", "--threads", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert (run / "best.pt").is_file()
    result = runner.invoke(app, ["evaluate", "segmentation", "--model", str(run / "best.pt"), "--data",
                                 str(tmp_path / "ds"), "--split", "test", "--fps-seconds", "0",
                                 "--threads", "1", "--json", str(tmp_path / "eval.json")])
    assert result.exit_code == 0, result.output
    scores = json.loads((tmp_path / "eval.json").read_text())["splits"]["test"]
    assert scores["frames"] == 1 and scores["by_height_m"] == []
    result = runner.invoke(app, ["export", "--checkpoint", str(run / "best.pt"), "--out",
                                 str(tmp_path / "m.onnx"), "--calibration-data", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "m.onnx").is_file()


def test_coco_annotations_that_would_give_a_wrong_mask_cost_their_frame(tmp_path):
    """From a review of the importers: an empty segmentation list (how CVAT's and
    Roboflow's COCO exports write a rectangle, its shape in bbox only) was dropped without a
    word and the boat imported as water; a flat list of numbers gave eight misleading
    messages; a polygon wholly outside the image (coordinates of another image) painted
    nothing; ids that are lists stopped the import with a TypeError. Each now costs its frame,
    named; a category id used twice with two names costs the file. The good frame is
    imported."""
    src = tmp_path / "src"
    for name in ("good", "boxonly", "flat", "away", "oddid"):
        write_image(src / f"{name}.png")
    poly = [np.ravel(L_SHAPE).tolist()]
    doc = coco_doc([(1, "good.png"), (2, "boxonly.png"), (3, "flat.png"), (4, "away.png"),
                    (5, "oddid.png")], [
        {"image_id": 1, "category_id": 1, "segmentation": poly},
        {"image_id": 2, "category_id": 1, "segmentation": [], "bbox": [5, 5, 20, 10]},
        {"image_id": 3, "category_id": 1, "segmentation": [5, 5, 30, 5, 30, 30, 5, 30]},
        {"image_id": 4, "category_id": 1, "segmentation": [[500, 500, 600, 500, 600, 600]]},
        {"image_id": 5, "category_id": [1], "segmentation": poly},
    ], ["ship"])
    doc["images"].append({"id": [6], "file_name": "good.png", "width": W, "height": H})
    result = invoke(write_json(src / "instances.json", doc), "-f", "coco", "--out", tmp_path / "ds")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["split"] == {"good": "train"}
    skipped = {s["field"]: s["reason"] for s in meta["skipped"]}
    assert "empty: a box-only annotation (bbox [5, 5, 20, 10])" in skipped["annotations[1].segmentation"]
    assert "one flat list of numbers" in skipped["annotations[2].segmentation"]
    assert "wholly outside the 60x40 image" in skipped["annotations[3].segmentation"]
    assert "no category with id [1]" in skipped["annotations[4].category_id"]
    assert "expected a whole number or a string" in skipped["images[5].id"]
    doc["categories"].append({"id": 1, "name": "obstacle"})
    result = invoke(write_json(src / "twice.json", doc), "-f", "coco", "--out", tmp_path / "ds2")
    assert "categories[1].id: id 1 is used twice ('ship', 'obstacle')" in result.output


def test_yolo_lines_in_pixels_and_a_far_vertex_cost_their_frame_not_the_import(tmp_path):
    """A YOLO line written in pixels instead of fractions was imported as water with the
    warning "cut off at the image edge"; it costs its frame, saying so. A LabelMe vertex at
    x = 4e8 (a typo for 40) made pycocotools overflow and crash the process; the ring is
    clipped to the image grown by a pixel first, which paints what the unclipped ring would
    (against pycocotools on a moderate far vertex)."""
    write_image(tmp_path / "images" / "train" / "pix.png")
    write_image(tmp_path / "images" / "train" / "ok.png", seed=1)
    (tmp_path / "data.yaml").write_text("names:\n  0: boat\n")
    (tmp_path / "labels" / "train").mkdir(parents=True)
    (tmp_path / "labels" / "train" / "pix.txt").write_text("0 10 5 30 5 30 20\n")
    line = " ".join(f"{x / W:.6f} {y / H:.6f}" for x, y in TRIANGLE)
    (tmp_path / "labels" / "train" / "ok.txt").write_text(f"0 {line}\n")
    result = invoke(tmp_path / "labels", "--format", "yolo", "--out", tmp_path / "ds", "--map", "boat=ship")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["split"] == {"ok": "train"}
    assert "fractions of the image's size, and this shape goes up to 30 (pixels?)" in result.output
    far = Polygons((np.array([[5.0, 5.0], [4e8, 8.0], [30.0, 30.0], [5.0, 30.0]]),))
    assert far.rasterise(H, W).any()                          # no crash, something painted
    moderate = [(5.0, 5.0), (2000.0, 8.0), (30.0, 30.0), (5.0, 30.0)]
    clipped = Polygons((np.array(moderate),))
    import harborsight.datasets.annotations as annotations_module

    assert annotations_module.FAR_OUTSIDE * W < 2000.0          # this one is clipped too
    assert np.array_equal(clipped.rasterise(H, W), coco_polygon(moderate))


def test_labelme_paths_of_another_machine_and_folders_given_twice(tmp_path):
    """An imagePath of the machine it was drawn on (C:\\Users\\...) with the image beside the
    JSON was not found (and the message did not mention --images); a folder given with a
    subfolder of it refused the whole import ("annotated twice, also in the same file").
    The image is found by its name beside the JSON; each file is read once."""
    src = tmp_path / "lm" / "sub"
    write_image(src / "x.png")
    shape = {"label": "boat", "points": [[5, 5], [30, 5], [30, 30]], "shape_type": "polygon"}
    write_json(src / "x.json", labelme_doc("C:\\\\Users\\\\me\\\\survey\\\\x.png", [shape]))
    result = invoke(tmp_path / "lm", src, "-f", "labelme", "--out", tmp_path / "ds", "--map", "boat=ship")
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "ds" / "dataset.json").read_text())["split"] == {"x": "train"}
    assert labels_of(tmp_path / "ds", "x").max() == 1
    write_json(src / "x.json", labelme_doc("C:/Users/me/survey/elsewhere.png", [shape]))
    result = invoke(src, "-f", "labelme", "--out", tmp_path / "ds2", "--map", "boat=ship")
    assert "give --images FOLDER to look it up there by its name" in result.output


def test_a_shape_painted_over_whole_is_named(tmp_path):
    """A YOLO file lists a boat, then the pier polygon around it: the boat, drawn first, has
    no pixel left (the documented order: later over earlier). It was dropped without a word;
    it is now a warning naming it. The mask is as before."""
    write_image(tmp_path / "images" / "p.png")
    (tmp_path / "data.yaml").write_text("names:\n  0: boat\n  1: pier\n")
    (tmp_path / "labels").mkdir()
    boat = [(20, 15), (30, 15), (30, 25), (20, 25)]
    pier = [(5, 5), (55, 5), (55, 35), (5, 35)]
    line = " ".join(f"{x / W:.6f} {y / H:.6f}" for x, y in boat)
    pier_line = " ".join(f"{x / W:.6f} {y / H:.6f}" for x, y in pier)
    (tmp_path / "labels" / "p.txt").write_text(f"0 {line}\n1 {pier_line}\n")
    result = invoke(tmp_path / "labels", "--format", "yolo", "--out", tmp_path / "ds",
                    "--map", "boat=ship", "--map", "pier=obstacle")
    assert result.exit_code == 0, result.output
    assert "'boat' has no pixel left: painted over whole by shapes drawn after it" in result.output
    labels = labels_of(tmp_path / "ds", "p")
    assert (labels == 1).sum() == 0 and (labels == 2).sum() > 0


def test_an_annotation_of_a_turned_photo_s_stored_size_says_exif(tmp_path):
    """A JPEG stored 40 wide and 60 high with EXIF Orientation 6 is shown (and read) 60x40;
    a tool that ignores EXIF writes 40x60. The frame is skipped as of another size, and now
    the message says why."""
    from PIL import Image

    src = tmp_path / "src"
    src.mkdir()
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(np.zeros((60, 40, 3), np.uint8)).save(src / "j6.jpg", exif=exif)
    write_image(src / "good.png")
    poly = [np.ravel(L_SHAPE).tolist()]
    doc = coco_doc([(1, "j6.jpg"), (2, "good.png")],
                   [{"image_id": i, "category_id": 1, "segmentation": poly} for i in (1, 2)], ["ship"])
    doc["images"][0].update(width=40, height=60)
    result = invoke(write_json(src / "ann.json", doc), "-f", "coco", "--out", tmp_path / "ds")
    assert result.exit_code == 0, result.output
    assert "it has EXIF Orientation 6 and is 60x40 as shown" in " ".join(result.output.split())


def test_annotation_files_that_broke_the_readers_cost_their_file_or_frame(tmp_path):
    """Found by the importer targets of test_fuzz_parsers.py: each of these raised out of
    the reader (TypeError, OverflowError, LookupError, ValueError, RecursionError) instead
    of being named as a problem of its file or frame."""
    write_image(tmp_path / "pics" / "a.png")
    write_image(tmp_path / "pics" / "b.png", seed=1)
    square = {"label": "boat", "shape_type": "polygon", "points": [[5, 5], [30, 5], [30, 20], [5, 20]]}

    def problems(fmt: str, *paths: Path, classes: Path | None = None) -> list[str]:
        out = tmp_path / f"ds-{len(list(tmp_path.iterdir()))}"
        try:
            result = import_dataset(ImportOptions(fmt, list(paths), out, images_dir=tmp_path / "pics",
                                                  classes_path=classes,
                                                  class_map=parse_class_map(["boat=ship"])))
        except InputError as exc:
            return [str(exc)]
        return [str(issue) for issue in result.skipped]

    coco = coco_doc([(1, "a.png")], [{"image_id": 1, "category_id": 1,
                                       "segmentation": [[5, 5, 30, 5, 30, 20]]}], ["boat"])
    coco["categories"] = 1.5e-97                  # not a list: no shape's class can be known
    found = problems("coco", write_json(tmp_path / "c.json", coco))
    assert len(found) == 1 and "c.json: categories: expected a list of {id, name}, got 1.5e-97" in found[0]

    far = dict(square, points=[[5, 5], [30, 5], [30, 20], [10 ** 400, 20]])   # past a float
    (tmp_path / "lm").mkdir()
    (tmp_path / "lm" / "a.json").write_text(json.dumps(labelme_doc("a.png", [far])))
    write_json(tmp_path / "lm" / "b.json", labelme_doc("b.png", [square]))
    found = problems("labelme", tmp_path / "lm")
    assert len(found) == 1 and "a.json" in found[0] and "expected a list of [x, y] points" in found[0]

    xml = tmp_path / "a.xml"
    xml.write_text(cvat_xml([("a.png", "")]).replace('encoding="utf-8"', 'encoding="u-8"'))
    found = problems("cvat", xml)
    assert len(found) == 1 and "a.xml: invalid XML: unknown encoding: u-8" in found[0]

    long_number = json.dumps(labelme_doc("a.png", [square])).replace("40", "4" * 5000, 1)
    (tmp_path / "lm2").mkdir()
    (tmp_path / "lm2" / "a.json").write_text(long_number)
    (tmp_path / "lm2" / "b.json").write_text("[" * 100_000)
    found = problems("labelme", tmp_path / "lm2")
    assert len(found) == 2
    assert "a.json" in found[0] and "a whole number of 5000 digits" in found[0]
    assert "b.json" in found[1] and "nested too deep" in found[1]

    (tmp_path / "yolo").mkdir()
    (tmp_path / "yolo" / "a.txt").write_text("0 0.1 0.1 0.5 0.1 0.5 0.5\n")
    (tmp_path / "deep.yaml").write_text("{" * 3000)
    found = problems("yolo-seg", tmp_path / "yolo", classes=tmp_path / "deep.yaml")
    assert len(found) == 1 and "deep.yaml: not valid YAML: nested too deep" in found[0]


def test_a_dataset_json_nested_too_deep_is_named(tmp_path):
    """The dataset reader of train and evaluate names a dataset.json it cannot read, whatever
    the reason (here nesting deeper than Python's JSON reader goes)."""
    (tmp_path / "dataset.json").write_text("[" * 100_000)
    with pytest.raises(InputError, match=r"dataset\.json: not valid JSON: arrays or objects nested too deep"):
        list_frames([tmp_path])
