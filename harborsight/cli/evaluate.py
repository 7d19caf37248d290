"""``harborsight evaluate``: segmentation (the paper's Table II) and distance."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.table import Table

from harborsight.cli.app import (
    EXACT_INT8_HELP,
    FLIPS_HELP,
    MAX_MARGIN_PX,
    MAX_THREADS,
    OWN_RIM_HELP,
    OWN_RIM_PX,
    POSE_MARGIN_PX,
    REFINE_POSE_HELP,
    SEGMENT_GSD_HELP,
    SIGMA_HELP,
    Method,
    app,
    console,
    err_console,
    fmt_number,
    parse_sigma_options,
    split_names,
)
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_file, prepare_output_folder, strict_json, write_image
from harborsight.perception.segment_images import SegmentMode
from harborsight.progress import progress_report

if TYPE_CHECKING:  # imported by the commands that use them: the CLI starts faster
    from harborsight.clearance.measure import ClearanceSettings

evaluate_app = typer.Typer(rich_markup_mode=None, no_args_is_help=True,
                           help="Evaluate models against labelled data.")


app.add_typer(evaluate_app, name="evaluate")


@evaluate_app.callback()
def evaluate_callback() -> None:
    """Evaluate models against labelled data: segmentation (Table II) and distance."""


@evaluate_app.command("segmentation")
def evaluate_segmentation_command(
    data: Annotated[list[Path], typer.Option(
        help="Dataset folder (dataset.json, images/, labels/); repeat for several.")],
    model: Annotated[Path | None, typer.Option(
        help="A torch checkpoint (.pt) or an ONNX model (.onnx); or give --predictions.")] = None,
    split: Annotated[list[str] | None, typer.Option(
        help="Split(s) to score, one table row each [test].")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the metrics as JSON.")
                        ] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the table as Markdown.")] = None,
    fps_seconds: Annotated[float, typer.Option(
        min=0.0, max=600.0,
        help="Seconds of timing for the FPS column; 0 skips it.")] = 2.0,
    device: Annotated[str, typer.Option(help="Device of a torch checkpoint: cpu or cuda.")] = "cpu",
    threads: Annotated[int | None, typer.Option(
        min=1, max=MAX_THREADS,
        help="CPU threads (default: all).")] = None,
    height_bin_m: Annotated[float, typer.Option(
        min=0.0, max=10_000.0,
        help="Also score per drone height above water (frames/*.json), in bins of this many "
        "metres; 0: no breakdown.")] = 10.0,
    by_object: Annotated[bool, typer.Option(
        help="Also score every object on its own (instances/ masks): the share of its pixels "
        "taken for solid, per kind (simulator datasets) and per size in pixels.")] = False,
    mode: Annotated[SegmentMode | None, typer.Option(
        show_default=False,
        help="How an ONNX model meets frames of another size than its input: resize (stretch "
        "into the input), tiles (overlapping windows blended) or auto (pad frames no larger "
        "than the input, stretch larger ones), as in harborsight segment (see its --help); "
        "tiles and auto need an ONNX model. Default: auto for an ONNX model (what segment, "
        "run and live do), resize for a checkpoint.")
    ] = None,
    tile_overlap: Annotated[float | None, typer.Option(
        min=0.0, max=0.9, show_default=False,
        help="tiles: overlap of neighbouring windows, a fraction of a window [0.25].")] = None,
    tile_scale: Annotated[float | None, typer.Option(
        min=0.01, max=16.0, show_default=False,
        help="tiles: scale each frame by this factor before cutting windows [1.0].")] = None,
    max_side: Annotated[int | None, typer.Option(
        min=1, show_default=False,
        help="tiles: and at most this many pixels on the scaled frame's longer side.")] = None,
    predictions: Annotated[Path | None, typer.Option(
        help="Score the masks in this folder (<stem>.png, e.g. from harborsight segment) "
        "instead of running a model; a frame whose mask is missing, of another size, or "
        "outside the class ids 0-2 on a labelled pixel is listed and skipped (255 where the "
        "label is 255 is not scored).")] = None,
    flips: Annotated[int, typer.Option(help=FLIPS_HELP + " ONNX models only.")] = 1,
    exact_int8: Annotated[bool, typer.Option(help=EXACT_INT8_HELP)] = False,
) -> None:
    """Mean accuracy, IoU per class, mIoU, FPS, resolution and parameters (paper Table II)."""
    from harborsight.evaluation.segmentation import evaluate_segmentation
    from harborsight.perception.segment_images import SegmentOptions

    try:
        if (model is None) == (predictions is None):
            raise InputError(None, "--model", "give either --model or --predictions")
        if 0 < height_bin_m < 0.1:
            raise InputError(None, "--height-bin-m", "give 0 (no breakdown) or at least 0.1 m")
        for path, option in ((json_out, "--json"), (markdown, "--markdown")):
            if path is not None:
                prepare_output_file(path, option)
        if mode is None:      # as harborsight segment and the measuring pipelines do
            onnx = model is not None and model.suffix.lower() == ".onnx"
            mode = SegmentMode.auto if onnx else SegmentMode.resize
        options = SegmentOptions.from_options(mode, tile_overlap, tile_scale, max_side, flips)
        with progress_report("reading frames", None, console) as progress:

            def on_split(name: str, n_frames: int) -> None:
                progress.update(label=f"scoring {name}", total=n_frames, completed=0)

            result = evaluate_segmentation(
                model, data, split or ["test"], fps_seconds, device, threads,
                on_frame=lambda _: progress.advance(), height_bin_m=height_bin_m,
                by_object=by_object, on_split=on_split, options=options,
                predictions=predictions, reference_arithmetic=exact_int8)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    how = f"; mode {options.describe()}" if result.model.kind == "onnx" else ""
    source = (f"{result.model.network} ({result.model.kind}{how}): {model}"
              if predictions is None else f"masks in {predictions}")
    console.print(_scores_table(source, "split",
                                [(row.split, row.frames, row.scores) for row in result.rows]))
    for row in result.rows:
        if row.by_height_m:
            console.print(_scores_table(
                f"{row.split} by drone height", "height m",
                [(f"{h:g}", n, sc) for h, (n, sc) in sorted(row.by_height_m.items())]))
            if row.frames_without_height:
                console.print(f"{row.split}: {row.frames_without_height} frame(s) without "
                              "readable metadata are in the totals, not in the table by height",
                              highlight=False)
        if row.objects:
            from harborsight.evaluation.objects import markdown_object_table

            console.print(f"{row.split}: recall per object", highlight=False)
            console.print(markdown_object_table(row.objects), markup=False, highlight=False)
        for _, error in row.skipped:
            err_console.print(f"[red]skipped[/] ({row.split}) {escape(error)}", highlight=False)
    w, h = result.resolution_wh
    if predictions is None:
        console.print(f"speed {fmt_number(result.fps, 2)} FPS at {w}x{h}, "
                      f"{result.model.params or 0:,} parameters")
    if json_out:
        json_out.write_text(strict_json(result.to_dict(), indent=2) + "\n")
        console.print(f"JSON: {json_out}")
    if markdown:
        markdown.write_text(result.markdown())
        console.print(f"Markdown: {markdown}")


def _scores_table(title: str, key_header: str, rows: list[tuple[str, int, object]]) -> Table:
    """Rich table of (key, frames, SegmentationScores) rows: Table II's accuracy/IoU columns."""
    from harborsight.evaluation.segmentation import TABLE_IOU_COLUMNS

    table = Table(title=title, title_justify="left")
    for header in (key_header, "frames", "mean acc %",
                   *(f"IoU {n.lower()} %" for n, _ in TABLE_IOU_COLUMNS), "mIoU %"):
        table.add_column(header, justify="left" if header == "split" else "right")
    for key, frames, sc in rows:
        table.add_row(key, str(frames), fmt_number(100 * sc.mean_accuracy, 1),
                      *(fmt_number(100 * sc.iou[c], 1) for _, c in TABLE_IOU_COLUMNS),
                      fmt_number(100 * sc.miou, 1))
    return table


@evaluate_app.command("distance")
def evaluate_distance_command(
    data: Annotated[Path, typer.Option(help="Simulator dataset with ground truth (frames/*.json).")],
    out: Annotated[Path, typer.Option(help="Folder for sections.csv, summary.md/json and plots.")
                   ] = Path("out/evaluate-distance"),
    oracle: Annotated[bool, typer.Option(
        help="Measure on the simulator's exact labels (separates segmentation errors).")] = True,
    flat_world: Annotated[bool, typer.Option(
        help="Also measure on flat-world masks (scene footprints on the water plane): "
        "pixel quantisation alone, which separates the planar assumption.")] = False,
    model: Annotated[Path | None, typer.Option(
        help="Also measure on masks from this ONNX model; 'default' for the shipped one.")] = None,
    flips: Annotated[int, typer.Option(help="--model: " + FLIPS_HELP)] = 1,
    segment_gsd_m: Annotated[float, typer.Option(help="--model: " + SEGMENT_GSD_HELP)] = 0.0,
    methods: Annotated[str, typer.Option(help="Comma list of gsd, ground_plane.")
                       ] = "gsd,ground_plane",
    split: Annotated[str | None, typer.Option(help="Only frames of this split.")] = None,
    limit: Annotated[int | None, typer.Option(min=1, help="At most this many frames.")] = None,
    by_obstacle: Annotated[bool, typer.Option(
        help="Also attribute each true distance to the kind of object it is measured to "
        "(quay, pier, ship, ...; rebuilds each simulator scene, about 0.3 s a frame) and "
        "summarise the signed error per kind (by_obstacle.md/json) and the summed error per "
        "kind and per what the reported point lies on (error_budget.md/json).")] = False,
    worst: Annotated[int, typer.Option(
        min=0, help="Draw the N frames with the largest summed error of each configuration "
        "(overlay | simulator labels | measured masks) to worst/.")] = 0,
    pose_margin_px: Annotated[float, typer.Option(
        min=0.0, max=MAX_MARGIN_PX,
        help="Growth of the vessel's own image region for pose and mask error, as "
        "in measure [2 px]: wider hides more of a model's vessel blob spilling onto the "
        "water, and reports a touching obstacle that much farther away.")] = POSE_MARGIN_PX,
    own_rim_px: Annotated[int, typer.Option(min=0, max=MAX_MARGIN_PX, help=OWN_RIM_HELP)] = OWN_RIM_PX,
    refine_pose: Annotated[bool, typer.Option(help=REFINE_POSE_HELP)] = True,
    sigma: Annotated[list[str] | None, typer.Option(metavar="NAME=VALUE", help=SIGMA_HELP)] = None,
) -> None:
    """Per-section distance error against ground truth by altitude: CSV, Markdown, box and
    bar plots, side by side for each mask source and conversion method."""
    from harborsight.clearance.measure import ClearanceSettings
    from harborsight.clearance.pose_refinement import PoseRefinementSettings
    from harborsight.evaluation.distance import (
        attribute_obstacles,
        evaluate_frames,
        flat_world_masks,
        load_frames,
        markdown_table,
        model_masks,
        oracle_masks,
        truth_obstacle_kinds,
        write_outputs,
    )
    from harborsight.perception.flips import flip_views
    from harborsight.perception.gsd_scaling import pipeline_segmenter

    clearance = ClearanceSettings(pose_margin_px=pose_margin_px, own_rim_px=own_rim_px,
                                  pose_refinement=PoseRefinementSettings(enabled=refine_pose),
                                  sigma_options=parse_sigma_options(sigma))
    chosen = split_names(methods)
    bad = [m for m in chosen if m not in {m.value for m in Method}]
    if bad or not chosen:
        err_console.print(f"error: --methods: unknown {bad}; use gsd and/or ground_plane")
        raise typer.Exit(2)
    sources = []
    if oracle:
        sources.append(("oracle", oracle_masks))
    try:
        flip_views(flips)
        if flips != 1 and model is None:
            raise InputError(None, "--flips", "test-time flips are for --model's masks")
        if segment_gsd_m and model is None:
            raise InputError(None, "--segment-gsd-m", "the GSD a model sees is for --model's masks")
        prepare_output_folder(out, "--out", inputs=(data,))
        if flat_world:
            sources.append(("flat", flat_world_masks(data)))
        if model is not None:
            from harborsight.perception.default_model import load_default_segmenter

            segmenter = pipeline_segmenter(
                load_default_segmenter(None if str(model) == "default" else model), flips,
                segment_gsd_m)
            name = segmenter.sidecar.get("network") or Path(segmenter.path).stem
            name += f"+flips{flips}" if flips != 1 else ""
            target_gsd_m = getattr(segmenter, "target_gsd_m", None)
            name += f"+gsd{target_gsd_m:g}" if target_gsd_m else ""
            sources.append((f"model:{name}", model_masks(
                segmenter.segment_with_confidence,
                takes_gsd=getattr(segmenter, "takes_gsd", False))))
        if not sources:
            raise InputError(None, "--oracle/--model", "nothing to evaluate: keep --oracle, "
                             "or give --flat-world or --model")
        unreadable: list[tuple[str, str]] = []
        frames = load_frames(data, split, unreadable)[:limit]
        if not frames:
            raise InputError(data / "frames", None, "no frames" + (f" in split {split}" if split else ""))
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False)
        raise typer.Exit(2) from None
    results, skipped = [], list(unreadable)
    for masks_name, source in sources:
        for method in chosen:       # a display each: a log gets one closing line per pass
            with progress_report(f"{masks_name} {method}", len(frames), console) as progress:

                def done(stem: str, error: str | None, progress=progress) -> None:
                    progress.advance()
                    if error:
                        skipped.append((stem, error))

                results += evaluate_frames(data, frames, masks_name, source, method, done,
                                           clearance)
    if by_obstacle:
        kinds_of, kinds = truth_obstacle_kinds(data), {}
        with progress_report("obstacle kinds", len(frames), console) as progress:
            for frame in frames:
                stem = Path(frame["image"]).stem
                try:
                    kinds[stem] = kinds_of(frame)
                except (HarborsightError, KeyError, ValueError) as exc:
                    skipped.append((stem, f"obstacle kinds: {type(exc).__name__}: {exc}"))
                progress.advance()
        attribute_obstacles(results, kinds)
    written = write_outputs(results, out)
    drawn = _draw_worst_frames(data, frames, results, sources, chosen, out / "worst", worst,
                               skipped, clearance)
    print(markdown_table(written["rows"]))
    if written["by_obstacle"]:
        from harborsight.evaluation.distance import markdown_obstacle_table

        print(markdown_obstacle_table(written["by_obstacle"]))
    learned = [r for r in written["error_sources"] if r.masks.startswith("model:")]
    if learned:
        from harborsight.evaluation.distance import markdown_error_source_table

        print("Where the model's error comes from (the reported obstacle point in the "
              "simulator's masks):\n")
        print(markdown_error_source_table(learned))
    for (stem, error), times in Counter(skipped).items():   # once per frame and reason
        repeat = f" (in {times} evaluations)" if times > 1 else ""
        err_console.print(f"[red]skipped[/] {escape(f'{stem}: {error}{repeat}')}",
                          highlight=False)
    console.print(f"{len(frames)} frame(s), {len(results)} section results; "
                  f"written to {out}/ (sections.csv, summary.md, summary.json, "
                  + ", ".join(p.name for p in written["plots"])
                  + (", error_sources.md, error_sources.json" if written["error_sources"] else "")
                  + (", by_obstacle.md, by_obstacle.json" if written["by_obstacle"] else "")
                  + (", error_budget.md, error_budget.json" if written["error_budget"] else "")
                  + (f", {drawn} picture(s) in worst/" if drawn else "") + ")")


def _draw_worst_frames(data: Path, frames: list[dict], results: list, sources: list,
                       methods: list[str], out_dir: Path, count: int,
                       skipped: list[tuple[str, str]], clearance: ClearanceSettings) -> int:
    """``count`` worst frames of every (masks, method) as panels in ``out_dir``; a frame
    that cannot be drawn joins ``skipped``. Returns how many pictures were written."""
    from harborsight.evaluation.distance import draw_error_panel, worst_frames

    by_stem = {Path(f["image"]).stem: f for f in frames}
    written = 0
    for masks_name, source in sources:
        for method in methods:
            for rank, (stem, _) in enumerate(worst_frames(results, masks_name, method, count), 1):
                try:
                    panel = draw_error_panel(data, by_stem[stem], source, method, masks_name,
                                             clearance)
                except (HarborsightError, KeyError) as exc:
                    skipped.append((stem, f"worst-frame picture: {type(exc).__name__}: {exc}"))
                    continue
                out_dir.mkdir(parents=True, exist_ok=True)
                name = f"{masks_name.replace(':', '-')}-{method}-{rank:02d}-{stem}.png"
                if write_image(out_dir / name, panel):
                    written += 1
                else:
                    skipped.append((stem, f"worst-frame picture: {out_dir / name} could not "
                                          "be written"))
    return written


@evaluate_app.command("flight")
def evaluate_flight_command(
    run_dir: Annotated[Path, typer.Argument(
        metavar="RUN", help="A run's output folder (its sections.csv), or the CSV itself.")],
    flight: Annotated[Path, typer.Option(
        help="The simulated flight the run measured (frames/*.json with the flight's ground "
        "truth: simulate --sequence-frames).")],
    from_frame: Annotated[int, typer.Option(
        min=0, help="Leave out each scene's frames before this one (the tracker starts from "
        "its first readings).")] = 3,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the scores as JSON.")
                        ] = None,
) -> None:
    """A run of a simulated berthing flight against its ground truth, per scene: the
    distances' error per frame and filtered by the tracker, the error bars' calibration and
    the closest section's closing speed."""
    from dataclasses import asdict

    from harborsight.evaluation.flight import score_flight

    sections_csv = run_dir / "sections.csv" if run_dir.is_dir() else run_dir
    try:
        if json_out is not None:
            prepare_output_file(json_out, "--json")
        scores = score_flight(flight, sections_csv, from_frame)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False)
        raise typer.Exit(2) from None
    console.print(f"{sections_csv} against {flight}, from frame {from_frame} of each scene",
                  markup=False, highlight=False)
    for s in scores:
        lines = [f"scene {s.scene} ({fmt_number(s.altitude_m, 0)} m): {s.frames_measured} of "
                 f"{s.frames} frames, {s.estimates} sections compared, {s.missed} missed, "
                 f"{s.false} false",
                 f"  distance: MAE {fmt_number(s.mae_m, 3)} m per frame, "
                 f"{fmt_number(s.mae_filtered_m, 3)} m filtered; median "
                 f"{fmt_number(s.median_abs_error_m, 3)}, p95 {fmt_number(s.p95_abs_error_m, 3)} m",
                 f"  bars: truth within 1 sigma {_percent(s.within_sigma_share)} % (68 for a "
                 f"Gaussian), 2 sigma {_percent(s.within_2_sigma_share)} %, at or "
                 f"above the lower bound {_percent(s.lower_bound_share)} %"]
        if s.closing is None:
            lines.append("  closing speed: no frame to compare")
        else:
            lines.append(f"  closing speed: {s.closing.measured_mps:.3f} m/s, true "
                         f"{s.closing.true_mps:.3f}, error {s.closing.median_abs_error_mps:.3f} "
                         f"(closest section, {s.closing.samples} frames)")
        if s.still_speed_mps is not None:
            lines.append(f"  while the vessel lies still: {s.still_speed_mps:.3f} m/s shown "
                         f"(median magnitude, {s.still_frames} frames)")
        console.print("\n".join(lines), markup=False, highlight=False)
    if json_out is not None:
        json_out.write_text(strict_json({"schema": "harborsight.flight-score/1",
                                         "sections_csv": str(sections_csv), "flight": str(flight),
                                         "from_frame": from_frame,
                                         "scenes": [asdict(s) for s in scores]}, indent=2) + "\n")


def _percent(share: float | None) -> str:
    return fmt_number(None if share is None else 100.0 * share, 1)
