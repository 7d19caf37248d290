"""``harborsight segment``: label masks (and overlays) for image files of any size."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from harborsight.cli.app import (
    EXACT_INT8_HELP,
    FLIPS_HELP,
    app,
    console,
    err_console,
    load_segmenter,
)
from harborsight.errors import HarborsightError
from harborsight.perception.segment_images import SegmentMode
from harborsight.progress import progress_report

#: help of --mode, --tile-overlap, --tile-scale and --max-side, shared with evaluate segmentation
MODE_HELP = ("How a frame of another size than the model input (640x360 for the default "
             "model) is segmented. auto (default): a frame no larger than the input in either "
             "dimension (a 256x256 orthophoto tile) is enlarged without stretching until it "
             "fills the input in one dimension (360x360) and padded into one window, a larger "
             "one (a 4000x3000 still, a 2048x1536 photo) is stretched into the "
             "input as in resize; measured on real val frames this beats either mode alone "
             "(docs/results.md). resize: the whole frame is stretched into the model input "
             "(one model call) and the logits are resized back bilinearly to the frame before "
             "the argmax. tiles: the frame is scaled by --tile-scale (capped by --max-side), "
             "cut into windows of the model input overlapping by --tile-overlap (the last "
             "window flush with the right and bottom edges; a frame smaller than a window is "
             "padded to one by edge reflection), each window's logits are blended with a "
             "weight that falls toward the window's edges, and the blend is resized to the "
             "frame and argmaxed.")
TILE_OVERLAP_HELP = "tiles: overlap of neighbouring windows, a fraction of a window [0.25]."
TILE_SCALE_HELP = ("tiles: scale the frame by this factor before cutting windows, so that a "
                   "pixel covers about as much of the scene as in the training frames "
                   "(0.5: a 4000x3000 still becomes 2000x1500) [1.0: no scaling].")
MAX_SIDE_HELP = "tiles: and at most this many pixels on the scaled frame's longer side."


@app.command("segment")
def segment_command(
    inputs: Annotated[list[Path], typer.Argument(
        metavar="INPUT...", show_default=False,
        help="Image files (PNG, JPEG, TIFF, ...) and folders of them (*.png, *.jpg, *.jpeg, "
        "*.tif, *.tiff in any letter case, in natural order: frame_2 before frame_10).")],
    out: Annotated[Path, typer.Option(
        help="Folder for <stem>.png masks, overlays/ and segment.json.", show_default=False)],
    model: Annotated[Path | None, typer.Option(
        help="ONNX model (harborsight export). Default: the packaged model.")] = None,
    overlay: Annotated[bool, typer.Option(
        help="Also write overlays/<stem>.jpg: the image blended with the class colours (water "
        "blue, ship vermillion, obstacle yellow) and a legend.")] = False,
    mode: Annotated[SegmentMode, typer.Option(help=MODE_HELP)] = SegmentMode.auto,
    tile_overlap: Annotated[float | None, typer.Option(
        min=0.0, max=0.9, show_default=False, help=TILE_OVERLAP_HELP)] = None,
    tile_scale: Annotated[float | None, typer.Option(
        min=0.01, max=16.0, show_default=False, help=TILE_SCALE_HELP)] = None,
    max_side: Annotated[int | None, typer.Option(min=1, show_default=False, help=MAX_SIDE_HELP)
                        ] = None,
    recursive: Annotated[bool, typer.Option(
        help="Also search the folders' subfolders; their masks go in the same subfolders of "
             "--out (a drone restarts its numbering in each folder).")] = False,
    flips: Annotated[int, typer.Option(help=FLIPS_HELP)] = 1,
    exact_int8: Annotated[bool, typer.Option(help=EXACT_INT8_HELP)] = False,
) -> None:
    """Write a label mask for each image: OUT/<stem>.png, one channel, uint8, at the image's
    own size; 0 water, 1 ship, 2 obstacle; 255 where the image holds no picture (alpha 0, as
    an orthophoto's area outside its footprint: filled black for the model, then unlabelled).

    OUT/segment.json records the model (file, network, held-out mIoU), the mode and its
    parameters, and per image its path, size, mask, share of each class, share without a
    picture and segmentation time; and the images left out, with the reason. An image that
    cannot be read (corrupt, empty, not an image), or whose stem an earlier image already
    took (a.png and a.jpg), is listed and left out; the others are still written.

    Exit status: 0 when at least one mask was written (left-out images are listed);
    1 when none was; 2 for a usage error (missing input or model file, bad option).
    """
    from harborsight.perception.onnx_segmenter import SATURATING_CPU, UINT8_WEIGHTS
    from harborsight.perception.segment_images import (
        SegmentOptions,
        collect_images,
        segment_images,
    )

    try:
        options = SegmentOptions.from_options(mode, tile_overlap, tile_scale, max_side, flips)
        names: dict = {}
        paths = collect_images(inputs, recursive, names)
        segmenter = load_segmenter(model, exact_int8)
        arithmetic = segmenter.int8_arithmetic()
        if arithmetic == UINT8_WEIGHTS:
            console.print("int8 arithmetic: this CPU has no VNNI, so the int8 weights run as "
                          "uint8, whose fused kernels do not saturate", markup=False,
                          highlight=False)
        elif arithmetic == f"integer operators ({SATURATING_CPU})":
            console.print("int8 arithmetic: integer operators on a CPU without VNNI, whose "
                          "16-bit sums can saturate (a QDQ export does not)", markup=False,
                          highlight=False)
        console.print(f"mode: {options.describe()}; {len(paths)} image(s)", markup=False,
                      highlight=False)
        with progress_report("segment", len(paths), console, unit="images") as progress:
            run = segment_images(paths, segmenter, out, options, overlay,
                                 on_image=lambda _: progress.advance(), names=names)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    if run.images:
        mean_ms = sum(image.time_ms for image in run.images) / len(run.images)
        console.print(f"[green]{len(run.images)} mask(s) written[/] to {escape(str(out))}/"
                      f"{' with overlays/' if overlay else ''} ({mean_ms:.0f} ms an image)",
                      highlight=False)
    if run.skipped:
        err_console.print(f"[red]{len(run.skipped)} image(s) left out:[/]")
        for path, reason in run.skipped:
            err_console.print(f"  {path}: {reason}", markup=False, highlight=False)
    console.print(f"summary: {run.json_path}", markup=False, highlight=False)
    raise typer.Exit(0 if run.images else 1)
