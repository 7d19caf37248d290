"""One line for a batch of frames: how the pose refinement came out on them."""

from __future__ import annotations

from typing import Any

import numpy as np

from harborsight.clearance.pose_refinement import SENSORS_FIT


def refinement_counts(refinements: list[dict[str, Any] | None]) -> dict[str, int]:
    """How a batch's frames came out: ``applied``, ``sensors_pose_fitted`` (kept, fitting as
    well), ``kept_sensors_pose`` (kept, the alignment not trusted) and ``off``; and, of them
    all, ``carried`` (the vessel's pose carried from earlier frames' images,
    :mod:`harborsight.flight.pose_carry`)."""
    given = [r for r in refinements if r]
    off = sum(r.get("reason") == "off" for r in given)
    applied = sum(bool(r.get("applied")) for r in given)
    fitted = sum(r.get("reason") == SENSORS_FIT for r in given)
    return {"applied": applied, "sensors_pose_fitted": fitted,
            "kept_sensors_pose": len(given) - off - applied - fitted, "off": off,
            "carried": sum(bool(r.get("carried_from")) for r in given)}


def refinement_summary(refinements: list[dict[str, Any] | None]) -> str | None:
    """One line for a batch: on how many frames the pose was refined, on how many the
    sensors' pose fitted as well, and why the others kept it (reasons without their
    numbers, most common first; the line holds "kept" only then). None when it was off."""
    counts = refinement_counts(refinements)
    ran = counts["applied"] + counts["sensors_pose_fitted"] + counts["kept_sensors_pose"]
    if not ran:
        return None
    line = f"pose refined on {counts['applied']} of {ran} frame(s)"
    contradicted = sum(bool(r and r.get("sensors_contradicted")) for r in refinements)
    if contradicted:
        line = (f"the image contradicts the sensors' pose on {contradicted} frame(s): their "
                "distances' lower bounds and clear reaches are 0; ") + line
    if counts["sensors_pose_fitted"]:
        line += f"; the sensors' pose fitted as well on {counts['sensors_pose_fitted']}"
    if counts["carried"]:
        line += (f"; the vessel's pose carried from earlier frames' images on "
                 f"{counts['carried']} (its reports too old)")
    kept = [str(r.get("reason") or "") for r in refinements
            if r and not r.get("applied") and r.get("reason") not in ("off", SENSORS_FIT)]
    if kept:
        kinds: dict[str, int] = {}
        for reason in kept:
            kind = " ".join("".join(ch for ch in reason if not (ch.isdigit() or ch in ".-+")).split())
            kinds[kind] = kinds.get(kind, 0) + 1
        top = sorted(kinds.items(), key=lambda kv: -kv[1])[:3]
        line += f"; the sensors' pose kept on {len(kept)} (" + "; ".join(
            f"{n}x {kind}" for kind, n in top) + ")"
    return line + _scale_note(refinements)


#: a batch whose frames' hulls put the scale off by this share (median) gets a note, from
#: :data:`SCALE_NOTE_MIN_FRAMES` frames whose correction was applied or the scale test fired
SCALE_NOTE_SHARE = 0.02
SCALE_NOTE_MIN_FRAMES = 5


def _scale_note(refinements: list[dict[str, Any] | None]) -> str:
    """A clause for a batch whose hulls, frame after frame, are larger or smaller in the
    image than the altitude and focal length say (``scale_change``, median over the frames
    that applied a correction or re-solved the scale): one frame's scale may be a mask's
    error, a flight's median is the camera's or the altimeter's. Held by its prior, a frame
    corrects only part of a focal length 5 % off (a median 2 % on the bench), so the note
    starts at :data:`SCALE_NOTE_SHARE`; with right sensors the bench's median was under
    0.5 %. "" when there is nothing to say."""
    changes = [float(r["scale_change"]) for r in refinements
               if r and r.get("scale_change") is not None
               and (r.get("applied") or r.get("scale_prior_m") is not None)]
    if len(changes) < SCALE_NOTE_MIN_FRAMES:
        return ""
    median = float(np.median(changes))
    if abs(median) < SCALE_NOTE_SHARE:
        return ""
    side = "lower" if median < 0 else "higher"
    return (f"; the hull's size in the image puts the drone a median {100 * abs(median):.1f} % "
            f"{side} than its altitude on {len(changes)} frame(s): check the camera's focal "
            "length (a video mode or stabilisation that crops the sensor) and the altitude")
