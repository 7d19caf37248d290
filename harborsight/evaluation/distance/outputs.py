"""A distance evaluation's files: the per-section CSV (written and read back), the
summaries as JSON and Markdown, the paper's two plots, and a frame's error panel."""

from __future__ import annotations

import csv
import dataclasses
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from harborsight.clearance.measure import ClearanceSettings, measure_frame
from harborsight.evaluation.distance.masks import MaskSource, oracle_masks, split_mask
from harborsight.evaluation.distance.results import SectionResult
from harborsight.evaluation.distance.summaries import (
    AltitudeSummary,
    markdown_error_budget_table,
    markdown_error_source_table,
    markdown_obstacle_table,
    markdown_table,
    summarise,
    summarise_by_obstacle,
    summarise_error_budget,
    summarise_error_sources,
)
from harborsight.files import strict_json
from harborsight.frame import parse_frame_metadata
from harborsight.vessel.spec import load_vessel_spec


def write_csv(results: list[SectionResult], path: Path) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["frame", "altitude_m", "masks", "method", "section", "status", "kind",
                         "estimate_m", "truth_m", "abs_error_m", "gsd_m_per_px", "contact",
                         "truncated", "obstacle", "point_truth", "sigma_m", "lower_m",
                         "clear_to_m", "flagged"])
        for r in results:
            err = r.abs_error_m
            writer.writerow([r.frame, r.altitude_m, r.masks, r.method, r.section, r.status, r.kind,
                             "" if r.estimate_m is None else f"{r.estimate_m:.4f}",
                             "" if r.truth_m is None else f"{r.truth_m:.4f}",
                             "" if err is None else f"{err:.4f}", f"{r.gsd_m_per_px:.5f}",
                             int(r.contact), int(r.truncated), r.obstacle or "",
                             r.point_truth or "",
                             "" if r.sigma_m is None else f"{r.sigma_m:.4f}",
                             "" if r.lower_m is None else f"{r.lower_m:.4f}",
                             "" if r.clear_to_m is None else f"{r.clear_to_m:.4f}",
                             int(r.flagged)])


def read_csv(path: Path) -> list[SectionResult]:
    """The results of :func:`write_csv` again (to re-plot or re-summarise without measuring)."""
    def number(text: str) -> float | None:
        return float(text) if text else None

    with path.open(newline="") as f:
        return [SectionResult(row["frame"], float(row["altitude_m"]), row["masks"], row["method"],
                              int(row["section"]), row["status"], number(row["estimate_m"]),
                              number(row["truth_m"]), float(row["gsd_m_per_px"]),
                              bool(int(row["contact"])), bool(int(row["truncated"])),
                              row.get("obstacle") or None, row.get("point_truth") or None,
                              number(row.get("sigma_m", "")), number(row.get("lower_m", "")),
                              number(row.get("clear_to_m", "")),
                              bool(int(row.get("flagged") or 0)))
                for row in csv.DictReader(f)]


def _finish(fig, ax, altitudes: list[float], ylabel: str, title: str, path: Path) -> Path:
    """Altitude ticks, labels, grid and legend; save the figure to ``path`` and close it."""
    import matplotlib.pyplot as plt

    ax.set_xticks(np.arange(len(altitudes)), [f"{a:.0f}" for a in altitudes])
    ax.set_xlabel("drone height above water (m)")
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_errors(results: list[SectionResult], rows: list[AltitudeSummary], out_dir: Path) -> list[Path]:
    """The paper's two figures: box plot of |error| per altitude, bar plot of MAE ± std;
    one box / bar per configuration at each altitude."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = sorted({(r.masks, r.method) for r in results})
    altitudes = sorted({r.altitude_m for r in results})
    width = 0.8 / max(1, len(configs))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    paths = []
    figsize = (min(14.0, max(8.0, 0.55 * len(altitudes) * max(1, len(configs)) ** 0.5)), 4.5)

    fig, ax = plt.subplots(figsize=figsize)
    for c, (masks, method) in enumerate(configs):
        data = [[r.abs_error_m for r in results if r.kind == "estimate" and r.masks == masks
                 and r.method == method and r.altitude_m == a] for a in altitudes]
        positions = np.arange(len(altitudes)) + (c - (len(configs) - 1) / 2) * width
        keep = [i for i, d in enumerate(data) if d]
        if not keep:
            continue
        bp = ax.boxplot([data[i] for i in keep], positions=positions[keep], widths=width * 0.85,
                        showfliers=True, patch_artist=True, flierprops={"markersize": 2})
        for patch in bp["boxes"]:
            patch.set_facecolor(colours[c % len(colours)])
            patch.set_alpha(0.6)
        ax.plot([], [], color=colours[c % len(colours)], lw=6, alpha=0.6, label=f"{masks}, {method}")
    ax.set_yscale("symlog", linthresh=0.1)
    paths.append(_finish(fig, ax, altitudes, "absolute distance error (m)",
                         "Absolute distance error per section", out_dir / "distance_error_box.png"))

    fig, ax = plt.subplots(figsize=figsize)
    for c, (masks, method) in enumerate(configs):
        sel = {r.altitude_m: r for r in rows if r.masks == masks and r.method == method}
        mae = [sel[a].mae_m if a in sel and sel[a].mae_m is not None else np.nan for a in altitudes]
        std = [sel[a].std_m if a in sel and sel[a].std_m is not None else np.nan for a in altitudes]
        positions = np.arange(len(altitudes)) + (c - (len(configs) - 1) / 2) * width
        below = np.minimum(std, mae)            # an absolute error is never below zero
        ax.bar(positions, mae, width * 0.9, yerr=[below, std], capsize=2,
               label=f"{masks}, {method}",
               color=colours[c % len(colours)], alpha=0.8)
    paths.append(_finish(fig, ax, altitudes, "mean absolute error (m), ± std",
                         "Mean absolute distance error", out_dir / "distance_mae_bar.png"))
    return paths


def worst_frames(results: list[SectionResult], masks_name: str, method: str, count: int
                 ) -> list[tuple[str, float]]:
    """The ``count`` frames of one configuration with the largest summed absolute error
    over their estimates, as ``(stem, summed error m)``, worst first."""
    totals: dict[str, float] = {}
    for r in results:
        if r.masks == masks_name and r.method == method and r.kind == "estimate":
            totals[r.frame] = totals.get(r.frame, 0.0) + r.abs_error_m
    return sorted(totals.items(), key=lambda kv: -kv[1])[:count]


def draw_error_panel(dataset: Path, frame: dict, masks: MaskSource, method: str,
                     title: str, clearance: ClearanceSettings | None = None) -> np.ndarray:
    """One frame measured again and drawn as three panels side by side: the overlay of the
    report (distances, obstacle points), the simulator's labels and the measured masks, both
    with the vessel's sections and the reported obstacle points, so a wrong distance can be
    traced to the pixels that caused it."""
    from harborsight.images import read_image
    from harborsight.viz.contact_sheet import colourise_labels
    from harborsight.viz.overlay import YELLOW, draw_banner, draw_overlay

    stem = Path(frame["image"]).stem
    meta = parse_frame_metadata(frame, dataset / "frames" / f"{stem}.json",
                                base_dir=dataset / "frames")
    image = read_image(dataset / "images" / frame["image"])
    measured, confidence = split_mask(masks(dataset, frame))
    report = measure_frame(measured, meta, load_vessel_spec(dataset / frame["vessel_spec"]),
                           dataclasses.replace(clearance or ClearanceSettings(), method=method),
                           mask_from_file=masks is oracle_masks, confidence=confidence)
    truth = [t["distance_m"] for t in frame["ground_truth"]["sections"]]
    truth_text = " ".join("-" if t is None else f"{t:.1f}" for t in truth)
    panels = [draw_overlay(image, report, footer=f"true m: {truth_text}")]
    for labels, name in ((oracle_masks(dataset, frame), "simulator labels"),
                         (measured, f"{title} masks")):
        panel = colourise_labels(labels)
        for s in report.sections:
            hull = np.asarray(s.hull_px, float)
            if np.isfinite(hull).all():
                cv2.line(panel, tuple(np.round(hull[0]).astype(int)),
                         tuple(np.round(hull[1]).astype(int)), (255, 255, 255), 1, cv2.LINE_AA)
            if s.obstacle_point_px:
                cv2.circle(panel, tuple(np.round(s.obstacle_point_px).astype(int)), 3, YELLOW, -1,
                           cv2.LINE_AA)
        draw_banner(panel, f"{stem}: {name}")
        panels.append(panel)
    return np.hstack(panels)


def write_outputs(results: list[SectionResult], out_dir: Path) -> dict:
    """CSV of every estimate, summary JSON and Markdown, the two plots, error_sources.json
    and .md when obstacle points were traced, and, when results carry obstacle kinds,
    by_obstacle.json and .md and error_budget.json and .md."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summarise(results)
    write_csv(results, out_dir / "sections.csv")
    (out_dir / "summary.json").write_text(strict_json([asdict(r) for r in rows], indent=1) + "\n")
    (out_dir / "summary.md").write_text(markdown_table(rows))
    plots = plot_errors(results, rows, out_dir) if results else []
    by_obstacle = summarise_by_obstacle(results)
    if by_obstacle:
        (out_dir / "by_obstacle.json").write_text(
            strict_json([asdict(r) for r in by_obstacle], indent=1) + "\n")
        (out_dir / "by_obstacle.md").write_text(markdown_obstacle_table(by_obstacle))
    budget = summarise_error_budget(results)
    if budget:
        (out_dir / "error_budget.json").write_text(
            strict_json([asdict(r) for r in budget], indent=1) + "\n")
        (out_dir / "error_budget.md").write_text(markdown_error_budget_table(budget))
    sources = summarise_error_sources(results)
    if sources:
        (out_dir / "error_sources.json").write_text(
            strict_json([asdict(r) for r in sources], indent=1) + "\n")
        (out_dir / "error_sources.md").write_text(markdown_error_source_table(sources))
    return {"rows": rows, "plots": plots, "by_obstacle": by_obstacle, "error_sources": sources,
            "error_budget": budget}
