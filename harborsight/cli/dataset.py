"""``harborsight dataset``: labelled datasets from annotation tools (a thin shell over
:mod:`harborsight.datasets`)."""

from __future__ import annotations

from collections import Counter
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from harborsight.cli.app import app, console, err_console
from harborsight.errors import HarborsightError
from harborsight.files import check_output_folder
from harborsight.progress import progress_report

dataset_app = typer.Typer(rich_markup_mode=None, no_args_is_help=True,
                          help="Labelled datasets: import annotations made with COCO, LabelMe, "
                          "CVAT or YOLO tools; masks proposed from boxes or for marina tiles.")
app.add_typer(dataset_app, name="dataset")

#: issues printed one per line; the rest are counted (all are in dataset.json)
SHOWN_ISSUES = 20


class Background(StrEnum):
    water = "water"
    ignore = "ignore"


@dataset_app.callback()
def dataset_callback() -> None:
    """Labelled datasets: import annotations made with COCO, LabelMe, CVAT or YOLO tools into
    harborsight's dataset layout (images/, labels/, dataset.json) for train and evaluate."""


def _print_issues(title: str, style: str, issues: list) -> None:
    if not issues:
        return
    err_console.print(f"[{style}]{len(issues)} {title}[/]" + (" (all in dataset.json)" if
                                                                 len(issues) > SHOWN_ISSUES else ""))
    for issue in issues[:SHOWN_ISSUES]:
        err_console.print(f"  {issue}", markup=False, highlight=False)
    if len(issues) > SHOWN_ISSUES:
        err_console.print(f"  ... and {len(issues) - SHOWN_ISSUES} more", highlight=False)


@dataset_app.command("import")
def import_command(
    sources: Annotated[list[Path], typer.Argument(
        metavar="SOURCE...", show_default=False,
        help="coco: instances JSON file(s). labelme: JSON files or folders of them. cvat: "
        "annotations.xml file(s). yolo-seg: folder(s) of .txt label files.")],
    fmt: Annotated[str, typer.Option(
        "--format", "-f", show_default=False,
        help="coco, labelme, cvat, yolo-seg (polygons) or yolo-boxes (refused: boxes are not "
        "masks; see `harborsight dataset label-from-boxes`).")],
    out: Annotated[Path, typer.Option(
        show_default=False, help="Dataset folder to write: new or empty (or see --append).")],
    images: Annotated[Path | None, typer.Option(
        help="Folder the annotations' image names are relative to (default: coco, cvat: the "
        "annotation file's folder, then images/ beside it; labelme: the JSON's folder; yolo: the "
        "images folder mirroring labels/).")] = None,
    classes: Annotated[Path | None, typer.Option(
        help="yolo: class names, data.yaml/classes.yaml (names:) or classes.txt (default: found "
        "beside the labels).")] = None,
    map_: Annotated[list[str] | None, typer.Option(
        "--map", help="NAME=CLASS: the annotations' class NAME (any letter case) is harborsight's "
        "water, ship, obstacle or ignore (or 0, 1, 2, 255); repeat for each name. The names "
        "water, ship, obstacle and ignore need none; any other name without one is an error.")
    ] = None,
    background: Annotated[Background, typer.Option(
        help="Class of the pixels no annotation covers: water (0) or ignore (255).")
    ] = Background.water,
    split: Annotated[str | None, typer.Option(
        help="Split of every imported frame: train, val or test (default: train).")] = None,
    split_file: Annotated[Path | None, typer.Option(
        help="CSV of stem,split lines giving each frame's split; every imported stem must be "
        "listed.")] = None,
    max_side: Annotated[int | None, typer.Option(
        min=1, help="Shrink images whose longer side is larger to this many pixels (image "
        "INTER_AREA, mask INTER_NEAREST_EXACT).")] = None,
    append: Annotated[bool, typer.Option(
        help="Add the frames to the dataset in --out (made by this command); a stem already "
        "there is an error.")] = False,
    keep_unlabelled: Annotated[bool, typer.Option(
        help="Also import images without any annotated region (all background); by default "
        "they are skipped and listed.")] = False,
    progress: Annotated[bool, typer.Option(help="Show the progress bar.")] = True,
) -> None:
    """Import annotations into a dataset folder: images/<stem>.<ext>, labels/<stem>.png (0
    water, 1 ship, 2 obstacle, 255 ignore) and dataset.json. Shapes are painted in order, a
    later one over an earlier one (CVAT z_order first, then file order); a class mapped to
    ignore paints 255 in its turn. Coordinates are continuous pixel positions (pixel (0, 0)
    covers 0..1 x 0..1); parts of shapes outside the image are cut off and reported as
    warnings. A frame whose image is missing or unreadable, whose annotation states another
    size than its image's, or which has no annotated region is skipped and listed (also in
    dataset.json); the others are imported. Exit code 0 if a frame was imported, 1 if none, 2
    for a bad option or a class name without a harborsight class (nothing written)."""
    from harborsight.datasets.classmap import TARGETS, parse_class_map
    from harborsight.datasets.layout import ImportOptions, plan_import, run_import
    from harborsight.errors import InputError

    try:
        if split is not None and split_file is not None:
            raise InputError(None, "--split", "give --split or --split-file, not both")
        options = ImportOptions(
            format=fmt, sources=list(sources), out_dir=out, images_dir=images,
            classes_path=classes, class_map=parse_class_map(map_ or []),
            background=TARGETS[background.value], split=split or "train", split_file=split_file,
            max_side=max_side, append=append, keep_unlabelled=keep_unlabelled)
        plan = plan_import(options)
        check_output_folder(out, "--out")
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    with progress_report("dataset import", len(plan.frames), console,
                         enabled=progress) as bar:
        result = run_import(plan, on_frame=lambda *_: bar.advance())
    _print_issues("frame(s) or file(s) skipped:", "red", result.skipped)
    _print_issues("warning(s) (frames imported):", "yellow", result.warnings)
    if not result.splits:
        err_console.print(f"no frame imported; nothing written to {out}", markup=False,
                          highlight=False)
        raise typer.Exit(1)
    console.print(f"[green]{len(result.splits)} frame(s) imported[/] from {plan.options.format} "
                  f"into {escape(str(out))}/", highlight=False)
    table = Table()
    table.add_column("split")
    table.add_column("frames", justify="right")
    for name, n in result.frames_per_split().items():
        table.add_row(name, str(n))
    console.print(table)
    fractions = result.pixel_fractions()
    console.print("pixels: " + ", ".join(f"{name} {100 * share:.1f}%" for name, share in
                                         fractions.items()), highlight=False)
    console.print(f"dataset: {out / 'dataset.json'}"
                  + (f"; {len(result.skipped)} skipped" if result.skipped else ""),
                  markup=False, highlight=False)


@dataset_app.command("label-from-boxes")
def label_from_boxes_command(
    labels_dir: Annotated[Path, typer.Argument(
        metavar="BOXES_DIR", show_default=False,
        help="Folder of YOLO box files (class cx cy w h, normalised), one per image.")],
    out: Annotated[Path, typer.Option(show_default=False, help="Dataset folder to write: new or empty.")],
    images: Annotated[Path | None, typer.Option(
        help="Folder of the images (default: the images folder mirroring labels/, or beside it).")
    ] = None,
    classes: Annotated[Path | None, typer.Option(
        help="Class names: data.yaml/classes.yaml (names:) or classes.txt (default: found beside "
        "the boxes).")] = None,
    map_: Annotated[list[str] | None, typer.Option(
        "--map", help="NAME=CLASS for each box class name: water, ship, obstacle or ignore. Boxes "
        "of ship classes are cut out by GrabCut and become ship; everything solid that is not "
        "in a ship box is obstacle; ignore boxes make their solid pixels 255.")] = None,
    split: Annotated[str | None, typer.Option(help="Split of every frame (default: train).")] = None,
    split_file: Annotated[Path | None, typer.Option(
        help="CSV of stem,split lines; every labelled image must be listed.")] = None,
    corrections: Annotated[Path | None, typer.Option(
        help="YAML of the reviewer's corrections per image stem (polygons or boxes with a class, "
        "optionally repainting only some classes; or exclude: reason). See "
        "harborsight.datasets.box_dataset.")] = None,
    max_side: Annotated[int | None, typer.Option(
        min=16, help="Shrink larger images (and their masks) to this long side before writing.")
    ] = None,
    review: Annotated[Path | None, typer.Option(
        help="Folder for the review sheets (default: OUT/review).")] = None,
    progress: Annotated[bool, typer.Option(help="Show the progress bar.")] = True,
) -> None:
    """Proposed label masks from boxes plus the image: water from texture and colour
    (GrabCut), vessels cut out of their boxes, everything else solid is obstacle, and 255 on
    unexplained islands in the water and along every class boundary. The reviewer's
    corrections are applied on top; the masks before correction go to OUT/proposals/, the
    reviewed ones to OUT/labels/, images (JPEG) to OUT/images/, review sheets (image |
    proposal | reviewed) to OUT/review/ and dataset.json records the agreement between
    proposals and reviewed masks. These are proposals: look at every review sheet. Exit code
    0 if an image was labelled, 1 if none, 2 for a bad option or class name."""
    from harborsight.datasets.box_dataset import read_corrections
    from harborsight.datasets.classmap import (
        find_class_names_file,
        parse_class_map,
        read_class_names,
        splits_of,
    )
    from harborsight.datasets.yolo import default_images_dir, read_yolo_boxes
    from harborsight.errors import InputError

    try:
        if not labels_dir.is_dir():
            raise InputError(labels_dir, None, "boxes folder not found")
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise InputError(out, None, "exists and is not an empty folder: give a new one")
        names_file = classes or find_class_names_file(labels_dir, labels_dir.parent)
        if names_file is None:
            raise InputError(labels_dir, "classes", "no class names found: give --classes")
        images_dir = images or default_images_dir(labels_dir)
        found, skipped = read_yolo_boxes(labels_dir, images_dir, read_class_names(names_file),
                                         parse_class_map(map_ or []))
        fixes = read_corrections(corrections) if corrections else None
        splits = splits_of([item.image_path.stem for item in found], split, split_file)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    _label_and_review(found, out, splits, review, progress, dict(
        corrections=fixes, max_side=max_side, skipped_before=skipped))


@dataset_app.command("label-marina")
def label_marina_command(
    inputs: Annotated[list[Path], typer.Argument(
        metavar="IMAGE_OR_FOLDER...", show_default=False,
        help="Nadir marina tiles (PNG, JPEG, TIFF) or folders of them.")],
    out: Annotated[Path, typer.Option(show_default=False, help="Dataset folder to write: new or empty.")],
    split: Annotated[str | None, typer.Option(help="Split of every frame (default: train).")] = None,
    split_file: Annotated[Path | None, typer.Option(
        help="CSV of stem,split lines; every labelled image must be listed.")] = None,
    corrections: Annotated[Path | None, typer.Option(
        help="YAML of the reviewer's corrections per image stem (as for label-from-boxes).")] = None,
    review: Annotated[Path | None, typer.Option(
        help="Folder for the review sheets (default: OUT/review).")] = None,
    progress: Annotated[bool, typer.Option(help="Show the progress bar.")] = True,
) -> None:
    """Proposed label masks for nadir marina tiles with no annotation at all: water by the
    colour of the darkest large region, per pixel (the gaps between moored boats are a few
    pixels wide); long, straight, narrow runs are pontoons (obstacle); wider line-like rows
    and thin parts are left undecided (255); greener-than-water solid is obstacle; every other
    solid pixel is ship. Shore with buildings, car parks or rip-rap is taken for ship: look
    at every review sheet and exclude or correct such tiles. Written like label-from-boxes
    (images/, labels/, proposals/, review/, dataset.json). Exit code 0 if a tile was
    labelled, 1 if none, 2 for a bad option."""
    from harborsight.datasets.box_dataset import read_corrections
    from harborsight.datasets.classmap import splits_of
    from harborsight.datasets.marina import label_marina_tile
    from harborsight.datasets.yolo import ImageBoxes, image_size_hw
    from harborsight.errors import InputError
    from harborsight.perception.segment_images import collect_images

    unreadable: list[tuple[str, str]] = []
    try:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise InputError(out, None, "exists and is not an empty folder: give a new one")
        tiles = []
        for path in collect_images(inputs):
            try:
                height, width = image_size_hw(path)
            except InputError as exc:
                unreadable.append((str(path), str(exc)))
                continue
            tiles.append(ImageBoxes(path, width, height, ()))
        fixes = read_corrections(corrections) if corrections else None
        splits = splits_of([t.image_path.stem for t in tiles], split, split_file)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    _label_and_review(tiles, out, splits, review, progress, dict(
        corrections=fixes, skipped_before=unreadable, generator="label-marina",
        proposer=lambda image, _boxes: label_marina_tile(image)), rows_per_sheet=8, tile_width=256)


def _label_and_review(items: list, out: Path, splits: dict[str, str], review: Path | None,
                      progress: bool, writer_options: dict, rows_per_sheet: int = 4,
                      tile_width: int = 384) -> None:
    """Propose, correct and write every image with a progress bar, list what was skipped,
    write the review sheets and say how much the review changed (exit 1 if nothing was
    labelled)."""
    from harborsight.datasets.box_dataset import write_box_dataset
    from harborsight.viz.review_sheet import review_sheets

    label = f"dataset {writer_options.get('generator', 'label-from-boxes')}"
    with progress_report(label, len(items), console, unit="images", enabled=progress) as bar:
        result = write_box_dataset(items, out, splits, on_image=lambda *_: bar.advance(),
                                   **writer_options)
    _print_issues("image(s) skipped:", "red", [f"{file}: {reason}" for file, reason in result.skipped])
    if not result.splits:
        err_console.print(f"no image labelled; nothing usable in {out}", markup=False, highlight=False)
        raise typer.Exit(1)
    sheets_dir = review or out / "review"
    sheets = review_sheets(out, sheets_dir, sorted(result.splits), rows_per_sheet, tile_width)
    agreement = list(result.agreement.values())
    console.print(f"[green]{len(result.splits)} image(s) labelled[/] into {escape(str(out))}/; "
                  f"proposal vs reviewed agreement {100 * sum(agreement) / len(agreement):.2f}% "
                  f"(mean over images); {len(sheets)} review sheet(s) in {escape(str(sheets_dir))}/",
                  highlight=False)


@dataset_app.command("label-tiles")
def label_tiles_command(
    positions: Annotated[Path, typer.Argument(
        metavar="POSITIONS_CSV", show_default=False,
        help="CSV naming each tile (tile_file) and its photo's stem (frame_id), optionally its "
        "top-left corner in the photo's original (x0/y0 or x0_native_WxH/y0_native_WxH).")],
    photo_dataset: Annotated[Path, typer.Option(
        show_default=False, help="The labelled photos: a dataset folder (labels/, dataset.json) "
        "whose stems are the photos' (e.g. from label-from-boxes).")],
    out: Annotated[Path, typer.Option(show_default=False, help="Dataset folder to write: new or empty.")],
    tiles: Annotated[Path | None, typer.Option(
        help="Folder of the tile images (default: tiles/ beside the CSV).")] = None,
    photos: Annotated[Path | None, typer.Option(
        help="Folder of the photos to register against, at the best resolution there is "
        "(default: the photo dataset's images/).")] = None,
    original_width: Annotated[int | None, typer.Option(
        min=1, help="Width of the originals the tiles were cut from (default: read from a "
        "column named x0_native_WxH, else the tiles are matched at the photos' own scale).")
    ] = None,
    max_side: Annotated[int | None, typer.Option(
        min=16, help="Shrink larger tiles (and their masks) to this long side before writing.")
    ] = None,
    min_inliers: Annotated[int, typer.Option(
        min=4, help="Feature matches a tile's own registration needs; a tile with fewer is "
        "placed by its photo's model (the other tiles' fits) if two tiles agree on one.")] = 20,
    min_ncc: Annotated[float, typer.Option(
        help="Refuse a placement whose tile vs warped photo correlation is lower.")] = 0.8,
    jpeg_quality: Annotated[int, typer.Option(
        min=1, max=100, help="JPEG quality of the written tiles.")] = 85,
    review: Annotated[Path | None, typer.Option(
        help="Folder for the review sheets (default: OUT/review).")] = None,
    progress: Annotated[bool, typer.Option(help="Show the progress bar.")] = True,
) -> None:
    """Label masks for tiles cut from labelled photos: each tile is registered to its photo
    (SIFT matches and a RANSAC similarity, or the photo's model from its other tiles, checked
    by normalised cross-correlation) and the photo's reviewed mask is warped onto it. Each
    tile goes into its photo's split. Writes images/ (JPEG), labels/, review sheets and
    dataset.json (every tile's placement, NCC and coverage; the tiles left out, with the
    reason). Look at the review sheets: the masks inherit the photos' review, and show it at a
    finer scale. Exit code 0 if a tile was labelled, 1 if none, 2 for a bad option."""
    import re

    from harborsight.datasets.photo_tiles import (
        TileRegistrationSettings,
        place_tiles,
        read_tile_positions,
        write_tile_dataset,
    )
    from harborsight.errors import InputError
    from harborsight.perception.segment_images import collect_images
    from harborsight.training.dataset import read_split_map
    from harborsight.viz.review_sheet import review_sheets

    try:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise InputError(out, None, "exists and is not an empty folder: give a new one")
        tiles_dir = tiles or positions.parent / "tiles"
        if not tiles_dir.is_dir():
            raise InputError(tiles_dir, None, "tiles folder not found")
        sources = read_tile_positions(positions, tiles_dir)
        photo_splits = read_split_map(photo_dataset)
        photos_dir = photos or photo_dataset / "images"
        if not photos_dir.is_dir():
            raise InputError(photos_dir, None, "photos folder not found")
        photo_paths = {p.stem: p for p in collect_images([photos_dir])}
        if original_width is None:
            header = positions.read_text(encoding="utf-8", errors="replace").splitlines()[0]
            found = re.search(r"x0_native_(\d+)x\d+", header)
            original_width = int(found.group(1)) if found else None
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    known = [s for s in sources if s.photo_stem in photo_splits]
    skipped = [(str(s.tile_path), f"photo {s.photo_stem!r} is not in the photo dataset")
               for s in sources if s.photo_stem not in photo_splits]
    settings = TileRegistrationSettings(min_inliers=min_inliers, min_ncc=min_ncc)
    with progress_report("dataset label-tiles", len(known), console, unit="tiles",
                         enabled=progress) as bar:
        placements, refused = place_tiles(known, photo_paths, original_width, settings,
                                          on_tile=lambda *_: bar.advance())
        result = write_tile_dataset(placements, photo_dataset, out, max_side,
                                    skipped_before=skipped + refused, jpeg_quality=jpeg_quality)
    _print_issues("tile(s) skipped:", "red", [f"{file}: {reason}" for file, reason in result.skipped])
    if not result.splits:
        err_console.print(f"no tile labelled; nothing usable in {out}", markup=False, highlight=False)
        raise typer.Exit(1)
    sheets_dir = review or out / "review"
    sheets = review_sheets(out, sheets_dir, sorted(result.splits), rows_per_sheet=12, tile_width=160)
    methods = ", ".join(f"{n} by {m}" for m, n in sorted(
        Counter(r["method"] for r in result.records.values()).items()))
    console.print(f"[green]{len(result.splits)} tile(s) labelled[/] into {escape(str(out))}/ "
                  f"({methods}); {len(sheets)} review sheet(s) in {escape(str(sheets_dir))}/",
                  highlight=False)

