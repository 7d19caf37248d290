"""Summaries of a distance evaluation's section results: per altitude (errors, misses,
calibration of the error bars), per kind of true nearest obstacle (signed error in pixels),
per source of segmentation error, and the error budget; each with its Markdown table."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harborsight.evaluation.distance.results import POINT_TRUTHS, SectionResult


@dataclass
class AltitudeSummary:
    altitude_m: float
    masks: str
    method: str
    n: int
    mae_m: float | None
    #: sample standard deviation of the absolute errors (n - 1 in the denominator); None below n = 2
    std_m: float | None
    median_m: float | None
    p95_m: float | None
    over_1m_share: float | None
    median_px: float | None
    missed: int
    false: int
    #: share of estimates within one and two reported sigmas of the truth (0.68 and 0.95
    #: when the sigmas are right and errors normal), share whose truth is at least the
    #: reported lower bound (0.95), and the median reported sigma
    within_sigma_share: float | None = None
    within_2_sigma_share: float | None = None
    lower_bound_share: float | None = None
    median_sigma_m: float | None = None
    #: sections with an obstacle in view whose band the report saw none of (``unseen``)
    unseen: int = 0
    #: sections (ok or clear) of frames whose pose the image contradicts: in the error
    #: figures, left out of the calibration shares
    flagged: int = 0


def _share(flags: list[bool | None]) -> float | None:
    known = [f for f in flags if f is not None]
    return float(np.mean(known)) if known else None


def summarise(results: list[SectionResult]) -> list[AltitudeSummary]:
    """Per (masks, method, altitude): error statistics and miss / false counts."""
    groups: dict[tuple, list[SectionResult]] = {}
    for r in results:
        groups.setdefault((r.masks, r.method, r.altitude_m), []).append(r)
    rows = []
    for (masks, method, altitude), group in sorted(groups.items(), key=lambda kv: kv[0]):
        errors = np.array([r.abs_error_m for r in group if r.kind == "estimate"])
        px = np.array([r.abs_error_m / r.gsd_m_per_px for r in group if r.kind == "estimate"])
        some = len(errors) > 0
        rows.append(AltitudeSummary(
            altitude, masks, method, len(errors),
            float(errors.mean()) if some else None,
            float(errors.std(ddof=1)) if len(errors) > 1 else None,
            float(np.median(errors)) if some else None,
            float(np.percentile(errors, 95)) if some else None,
            float(np.mean(errors > 1.0)) if some else None,
            float(np.median(px)) if some else None,
            sum(r.kind == "missed" for r in group), sum(r.kind == "false" for r in group),
            _share([r.within_sigmas(1) for r in group]), _share([r.within_sigmas(2) for r in group]),
            _share([r.lower_bound_holds for r in group]),
            _median([r.sigma_m for r in group if r.kind == "estimate"]),
            sum(r.kind == "unseen" for r in group), sum(r.flagged for r in group)))
    return rows


def _median(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return float(np.median(known)) if known else None


@dataclass
class ObstacleSummary:
    masks: str
    method: str
    obstacle: str
    n: int
    median_signed_px: float
    median_abs_px: float
    mae_m: float
    over_1px_share: float            # estimate - truth > +1 px (gap overestimated)
    under_1px_share: float           # estimate - truth < -1 px
    median_signed_px_by_altitude: dict[float, float]


def summarise_by_obstacle(results: list[SectionResult]) -> list[ObstacleSummary]:
    """Per (masks, method, true nearest obstacle kind): signed and absolute error in GSD
    pixels over all altitudes, and the median signed error per altitude."""
    groups: dict[tuple, list[SectionResult]] = {}
    for r in results:
        if r.kind == "estimate" and r.obstacle:
            groups.setdefault((r.masks, r.method, r.obstacle), []).append(r)
    rows = []
    for (masks, method, obstacle), group in sorted(groups.items()):
        signed = np.array([r.signed_error_px for r in group])
        by_altitude: dict[float, list[float]] = {}
        for r, e in zip(group, signed, strict=True):
            by_altitude.setdefault(r.altitude_m, []).append(e)
        rows.append(ObstacleSummary(
            masks, method, obstacle, len(group), float(np.median(signed)),
            float(np.median(np.abs(signed))), float(np.mean([r.abs_error_m for r in group])),
            float(np.mean(signed > 1.0)), float(np.mean(signed < -1.0)),
            {a: float(np.median(v)) for a, v in sorted(by_altitude.items())}))
    return rows


def markdown_obstacle_table(rows: list[ObstacleSummary]) -> str:
    """Two tables: per kind over all altitudes; median signed px per kind and altitude."""
    lines = ["| masks | method | nearest obstacle | n | median signed px | median abs px | "
             "MAE m | over > 1 px | under > 1 px |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | {r.n} | "
                     f"{r.median_signed_px:+.2f} | {r.median_abs_px:.2f} | {r.mae_m:.2f} | "
                     f"{100 * r.over_1px_share:.0f} % | {100 * r.under_1px_share:.0f} % |")
    altitudes = sorted({a for r in rows for a in r.median_signed_px_by_altitude})
    lines += ["", "Median signed error (px) by drone height above water (m):", "",
              "| masks | method | nearest obstacle | " + " | ".join(f"{a:.0f}" for a in altitudes)
              + " |", "|---|---|---|" + "---:|" * len(altitudes)]
    for r in rows:
        cells = [_fmt(r.median_signed_px_by_altitude.get(a)) for a in altitudes]
        lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


@dataclass
class ErrorSourceSummary:
    masks: str
    method: str
    altitude_m: float
    n: int                                # estimates with a traced obstacle point
    mae_m: float
    mae_on_obstacle_m: float | None       # MAE of the estimates whose point is a real obstacle
    count: dict[str, int]                 # estimates per point truth
    error_share: dict[str, float]         # share of the summed |error| per point truth
    false_obstacles: dict[str, int]       # false obstacles per point truth


def summarise_error_sources(results: list[SectionResult]) -> list[ErrorSourceSummary]:
    """Per (masks, method, altitude): how much of the absolute error comes from estimates
    whose obstacle point is a real obstacle, the vessel's own blob spilt onto water, or
    water taken for solid (module docstring); empty when no point was traced."""
    groups: dict[tuple, list[SectionResult]] = {}
    for r in results:
        if r.point_truth is not None:
            groups.setdefault((r.masks, r.method, r.altitude_m), []).append(r)
    rows = []
    for (masks, method, altitude), group in sorted(groups.items(), key=lambda kv: kv[0]):
        estimates = [r for r in group if r.kind == "estimate"]
        if not estimates:
            continue
        errors = np.array([r.abs_error_m for r in estimates])
        on_obstacle = errors[[r.point_truth == "obstacle" for r in estimates]]
        total = float(errors.sum())
        rows.append(ErrorSourceSummary(
            masks, method, altitude, len(estimates), float(errors.mean()),
            float(on_obstacle.mean()) if len(on_obstacle) else None,
            {t: sum(r.point_truth == t for r in estimates) for t in POINT_TRUTHS},
            {t: (float(sum(r.abs_error_m for r in estimates if r.point_truth == t)) / total
                 if total > 0 else 0.0) for t in POINT_TRUTHS},
            {t: sum(r.kind == "false" and r.point_truth == t for r in group) for t in POINT_TRUTHS}))
    return rows


@dataclass
class ErrorBudgetRow:
    masks: str
    method: str
    obstacle: str                     # kind of the true nearest obstacle
    point: str                        # what the reported point lies on (POINT_TRUTHS), or "missed"
    n: int                            # estimates (or missed sections) in the group
    mae_m: float | None               # None for misses: they have no distance to compare
    error_share: float                # share of the configuration's summed |error|
    wider_1m: int                     # estimates reading the gap > 1 m wider than it is
    narrower_1m: int                  # estimates reading it > 1 m narrower


def summarise_error_budget(results: list[SectionResult]) -> list[ErrorBudgetRow]:
    """Per (masks, method): the summed absolute error split by the kind of the true nearest
    obstacle and by what the reported point lies on, largest share first, then the missed
    obstacles per kind. Needs results with obstacle kinds (:func:`attribute_obstacles`);
    untraced points count as ``untraced``. A wider-than-true reading is the dangerous side."""
    configs: dict[tuple, list[SectionResult]] = {}
    for r in results:
        if r.obstacle and r.kind in ("estimate", "missed"):
            configs.setdefault((r.masks, r.method), []).append(r)
    rows: list[ErrorBudgetRow] = []
    for (masks, method), group in sorted(configs.items()):
        total = sum(r.abs_error_m for r in group if r.kind == "estimate")
        cells: dict[tuple, list[SectionResult]] = {}
        for r in group:
            point = "missed" if r.kind == "missed" else (r.point_truth or "untraced")
            cells.setdefault((r.obstacle, point), []).append(r)
        estimates, misses = [], []
        for (obstacle, point), cell in cells.items():
            if point == "missed":
                misses.append(ErrorBudgetRow(masks, method, obstacle, point, len(cell), None,
                                             0.0, 0, 0))
                continue
            signed = np.array([r.estimate_m - r.truth_m for r in cell])
            estimates.append(ErrorBudgetRow(
                masks, method, obstacle, point, len(cell), float(np.abs(signed).mean()),
                float(np.abs(signed).sum() / total) if total > 0 else 0.0,
                int((signed > 1.0).sum()), int((signed < -1.0).sum())))
        rows += sorted(estimates, key=lambda r: (-r.error_share, r.obstacle, r.point))
        rows += sorted(misses, key=lambda r: (-r.n, r.obstacle))
    return rows


def markdown_error_budget_table(rows: list[ErrorBudgetRow]) -> str:
    lines = ["| masks | method | nearest obstacle (truth) | reported point lies on | n | MAE m | "
             "share of summed error | wider by > 1 m | narrower by > 1 m |",
             "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        if r.point == "missed":
            lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | (missed) | {r.n} | — | — "
                         "| — | — |")
        else:
            lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | {r.point} | {r.n} | "
                         f"{_fmt(r.mae_m)} | {100 * r.error_share:.1f} % | {r.wider_1m} | "
                         f"{r.narrower_1m} |")
    return "\n".join(lines) + "\n"


def markdown_error_source_table(rows: list[ErrorSourceSummary]) -> str:
    lines = ["| masks | method | altitude m | n | MAE m | MAE m, point on a real obstacle | "
             "error share: real obstacle | vessel spill | false solid | "
             "false obstacles: vessel spill / false solid |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        share = " | ".join(f"{100 * r.error_share[t]:.0f} % ({r.count[t]})" for t in POINT_TRUTHS)
        lines.append(f"| {r.masks} | {r.method} | {r.altitude_m:.0f} | {r.n} | {r.mae_m:.2f} | "
                     f"{_fmt(r.mae_on_obstacle_m)} | {share} | "
                     f"{r.false_obstacles['vessel-spill']} / {r.false_obstacles['false-solid']} |")
    return "\n".join(lines) + "\n"


def _fmt(value: float | None, digits: int = 2) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _percent(share: float | None) -> str:
    return "—" if share is None else f"{100 * share:.0f} %"


def markdown_table(rows: list[AltitudeSummary]) -> str:
    lines = ["| masks | method | altitude m | n | MAE m (± std) | median m | median px | p95 m "
             "| > 1 m | missed | unseen | false | flagged | median sigma m | within 1 sigma "
             "| within 2 sigma | truth >= lower |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        share = "—" if r.over_1m_share is None else f"{100 * r.over_1m_share:.1f} %"
        mae = "—" if r.mae_m is None else f"{r.mae_m:.2f}" + (
            "" if r.std_m is None else f" ± {r.std_m:.2f}")
        lines.append(f"| {r.masks} | {r.method} | {r.altitude_m:.0f} | {r.n} | {mae} | "
                     f"{_fmt(r.median_m)} | {_fmt(r.median_px)} | {_fmt(r.p95_m)} | {share} | "
                     f"{r.missed} | {r.unseen} | {r.false} | {r.flagged} | "
                     f"{_fmt(r.median_sigma_m)} | "
                     f"{_percent(r.within_sigma_share)} | {_percent(r.within_2_sigma_share)} | "
                     f"{_percent(r.lower_bound_share)} |")
    return "\n".join(lines) + "\n"
