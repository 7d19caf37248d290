"""Distance error against the simulator's ground truth, per altitude (the paper's Sec. IV).

Each configuration (masks: ``oracle`` = the simulator's labels or a segmentation model; method:
``gsd`` or ``ground_plane``) is run on every frame of a dataset; every section is classed as

* an **estimate** (report ``ok``, truth has a visible obstacle): absolute error in metres and in
  GSD pixels;
* a **missed obstacle** (truth has one in view, the report says ``clear`` and saw some of
  the band's water: ``clear_to_m`` above 0);
* an **unseen** section (truth has one in view, the report says ``clear`` but saw none of
  the band: ``clear_to_m`` 0, a band the vessel hides in full or a frame whose pose the image
  contradicts): the report claims nothing there, so it is not counted as missed;
* a **false obstacle** (the report says ``ok``, the truth has nothing in view in that band).

Sections out of view are not counted. Summaries are per altitude (drone height above water,
rounded to whole metres): n, MAE, median, p95, share off by more than 1 m, missed, unseen,
false. Every estimate counts in the error figures; the calibration shares (within one and two
sigma, truth at or above the lower bound) leave out the sections of frames flagged
``sensors_contradicted``, whose bars are widened to the reading by construction (their lower
bound is 0), and the summary counts those sections apart.

With the obstacle attribution (:func:`truth_obstacle_kinds`), each estimate also carries the
kind of scene object its true distance is measured to (quay, pier, ship, boat, ...), and the
signed error ``estimate - truth`` in GSD pixels is summarised per kind: the planar
assumption errs by kind of structure (an edge ``h`` m above the water, ``r`` m from the
nadir, seen from ``H`` m, back-projects ``h·r/(H-h)`` m too far out), so this separates it.

Segmentation errors are traced the same way, pixel by pixel: each reported obstacle point is
looked up in the simulator's own masks (:func:`obstacle_point_truth`). A point within
:data:`POINT_TOLERANCE_PX` of a truly solid pixel of another object is a real obstacle (its
error is geometry and edge placement); a point on true water is a segmentation mistake,
``vessel-spill`` when the solid it lies on runs into the vessel's own region (the model's
blob of the vessel reaching out over the water, e.g. onto its shadow) and ``false-solid``
otherwise (a blob of water taken for solid). :func:`summarise_error_sources` gives each
kind's share of the summed absolute error per altitude; with the obstacle attribution too,
:func:`summarise_error_budget` splits the summed error by (true obstacle kind, point truth)
and counts the misses per kind, so a whole error can be read as a budget.

The parts: :mod:`.masks` (where the masks come from), :mod:`.results` (each section classed
against the truth), :mod:`.summaries` (the tables) and :mod:`.outputs` (the files and plots).
"""

from harborsight.evaluation.distance.masks import (
    MaskSource,
    flat_world_labels,
    flat_world_masks,
    model_masks,
    oracle_masks,
    scene_planner,
    split_mask,
)
from harborsight.evaluation.distance.outputs import (
    draw_error_panel,
    plot_errors,
    read_csv,
    worst_frames,
    write_csv,
    write_outputs,
)
from harborsight.evaluation.distance.results import (
    POINT_TOLERANCE_PX,
    POINT_TRUTHS,
    SectionResult,
    attribute_obstacles,
    evaluate_frames,
    load_frames,
    obstacle_point_truth,
    true_obstacle_mask,
    truth_obstacle_kinds,
)
from harborsight.evaluation.distance.summaries import (
    AltitudeSummary,
    ErrorBudgetRow,
    ErrorSourceSummary,
    ObstacleSummary,
    markdown_error_budget_table,
    markdown_error_source_table,
    markdown_obstacle_table,
    markdown_table,
    summarise,
    summarise_by_obstacle,
    summarise_error_budget,
    summarise_error_sources,
)

__all__ = [
    "POINT_TOLERANCE_PX",
    "POINT_TRUTHS",
    "AltitudeSummary",
    "ErrorBudgetRow",
    "ErrorSourceSummary",
    "MaskSource",
    "ObstacleSummary",
    "SectionResult",
    "attribute_obstacles",
    "draw_error_panel",
    "evaluate_frames",
    "flat_world_labels",
    "flat_world_masks",
    "load_frames",
    "markdown_error_budget_table",
    "markdown_error_source_table",
    "markdown_obstacle_table",
    "markdown_table",
    "model_masks",
    "obstacle_point_truth",
    "oracle_masks",
    "plot_errors",
    "read_csv",
    "scene_planner",
    "split_mask",
    "summarise",
    "summarise_by_obstacle",
    "summarise_error_budget",
    "summarise_error_sources",
    "true_obstacle_mask",
    "truth_obstacle_kinds",
    "worst_frames",
    "write_csv",
    "write_outputs",
]
