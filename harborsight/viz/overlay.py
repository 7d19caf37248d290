"""Overlay in the style of the paper's Fig. 1: sections, yellow distance lines, labels."""

from __future__ import annotations

import cv2
import numpy as np

from harborsight.clearance.report import STATUS_CLEAR, STATUS_OK, ClearanceReport
from harborsight.clearance.uncertainty import bounded_where_band_left, seen_lower_bound_m

YELLOW = (0, 230, 255)
GREEN = (80, 200, 60)
ORANGE = (0, 150, 255)
RED = (40, 40, 230)
GREY = (170, 170, 170)
WHITE = (255, 255, 255)
BLACK = (0, 0, 0)
MAGENTA = (255, 0, 255)
_SHIFT = 4
_SCALE = 1 << _SHIFT


def _fixed(point) -> tuple[int, int]:
    return round(point[0] * _SCALE), round(point[1] * _SCALE)


def _clipped(p0, p1, width: int, height: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of segment p0-p1 inside the image grown by its own size on every side, or
    None. A point just in front of the camera plane projects millions of pixels away, past
    what OpenCV's fixed-point drawing can hold; the clipped segment keeps its direction."""
    from shapely import LineString, clip_by_rect

    piece = clip_by_rect(LineString([tuple(p0), tuple(p1)]), -width, -height, 2 * width,
                         2 * height)
    if piece.is_empty or piece.geom_type != "LineString":
        return None
    a, b = np.asarray(piece.coords, float)[[0, -1]]
    return a, b


def _on_canvas(point, width: int, height: int) -> bool:
    return bool(np.isfinite(point).all() and -width <= point[0] <= 2 * width
                and -height <= point[1] <= 2 * height)


_FONT = cv2.FONT_HERSHEY_SIMPLEX
#: a label that would cover one already placed moves outward by its own height, at most
#: this many times, then sideways
_LABEL_TRIES = 6


def _label_box(text: str, anchor: np.ndarray, scale: float, shape: tuple[int, ...]
               ) -> tuple[int, int, int, int]:
    """The label's black box ``(x0, y0, x1, y1)`` centred on ``anchor``, kept in the picture."""
    thickness = max(1, round(scale * 2))
    (w, h), base = cv2.getTextSize(text, _FONT, scale, thickness)
    x = int(np.clip(anchor[0] - w / 2, 1, shape[1] - w - 2))
    y = int(np.clip(anchor[1] + h / 2, h + 2, shape[0] - base - 2))
    return x - 2, y - h - 2, x + w + 2, y + base


def _overlaps(box, others) -> bool:
    return any(box[0] < o[2] and o[0] < box[2] and box[1] < o[3] and o[1] < box[3] for o in others)


def _place_labels(image: np.ndarray, labels: list[tuple[str, np.ndarray, np.ndarray, tuple]],
                  scale: float, taken: list[tuple[int, int, int, int]]) -> None:
    """Draw ``(text, anchor, outward unit vector, colour)`` labels in order, each where it
    covers none placed before it (nor the boxes in ``taken``): at its anchor, else moved
    outward by its height up to :data:`_LABEL_TRIES` times, else sideways, else inward (at
    the picture's edge); where nothing is free, at its anchor."""
    thickness = max(1, round(scale * 2))
    placed = list(taken)
    for text, anchor, outward, colour in labels:
        box = _label_box(text, anchor, scale, image.shape)
        step = (box[3] - box[1]) + 2
        side = np.array([-outward[1], outward[0]])
        candidates = ([anchor + outward * step * k for k in range(_LABEL_TRIES + 1)]
                      + [anchor + side * step * k * sign for k in (1, 2) for sign in (1, -1)]
                      # at the picture's edge, outward is where it cannot go: inward then
                      + [anchor - outward * step * k for k in range(1, _LABEL_TRIES + 1)])
        for candidate in candidates:
            trial = _label_box(text, candidate, scale, image.shape)
            if not _overlaps(trial, placed):
                box = trial
                break
        placed.append(box)
        cv2.rectangle(image, box[:2], box[2:], BLACK, -1)
        base = cv2.getTextSize(text, _FONT, scale, thickness)[1]
        cv2.putText(image, text, (box[0] + 2, box[3] - base), _FONT, scale, colour, thickness,
                    cv2.LINE_AA)


def section_colour(distance_m: float | None, warn_m: float, alarm_m: float):
    if distance_m is None:
        return GREY
    if distance_m <= alarm_m:
        return RED
    if distance_m <= warn_m:
        return ORANGE
    return GREEN


def alarm_distance_m(section) -> float | None:
    """The distance the colours go by: the 95 % lower bound where the section has one (a
    section whose gap may be under the alarm distance shows red), else the distance; for a
    bound set where the section's band leaves the picture, the bound of the obstacle seen
    (as the live alarm does: what lies out of view is not a reason to show red)."""
    if bounded_where_band_left(section):
        return seen_lower_bound_m(section)
    return section.distance_m if section.distance_lower_m is None else section.distance_lower_m


def draw_overlay(
    image_bgr: np.ndarray, report: ClearanceReport, *, warn_m: float = 5.0, alarm_m: float = 2.0,
    footer: str | None = None,
) -> np.ndarray:
    """Copy of the image with every in-view section drawn and labelled.

    Sections are coloured by clearance (green > ``warn_m``, orange, red <= ``alarm_m``,
    grey when clear); a yellow line joins each section to its closest obstacle point; the
    distance in metres sits outside the section, ``??`` where the section is clear.
    When the image contradicts the sensors' pose, a magenta outline shows where the image
    puts the hull (the sections stay where the sensors put it).
    ``footer`` is a line of text on a band at the bottom (e.g. the closing speed).
    """
    out = image_bgr.copy()
    h, w = out.shape[:2]
    scale = max(0.35, min(w, h) / 900.0)
    thickness = max(2, round(min(w, h) / 220))
    image_hull = (report.pose_refinement or {}).get("image_hull_px")
    if report.sensors_contradicted and image_hull:
        corners = np.round(np.clip(np.asarray(image_hull, float), [-w, -h], [2 * w, 2 * h])
                           * _SCALE).astype(np.int32)
        cv2.polylines(out, [corners], True, MAGENTA, thickness, cv2.LINE_AA, _SHIFT)
    ends = [np.asarray(s.hull_px, float) for s in report.sections]
    anchors = [_label_anchor(s, end, w, h) for s, end in zip(report.sections, ends, strict=True)]
    known = [a for a in anchors if a is not None]
    centre = np.mean(known, axis=0) if known else np.array([w / 2.0, h / 2.0])

    for s, end in zip(report.sections, ends, strict=True):
        if s.status not in (STATUS_OK, STATUS_CLEAR) or not np.isfinite(end).all():
            continue
        colour = section_colour(alarm_distance_m(s), warn_m, alarm_m)
        piece = _clipped(end[0], end[1], w, h)
        if piece is not None:
            cv2.line(out, _fixed(piece[0]), _fixed(piece[1]), colour, thickness, cv2.LINE_AA,
                     _SHIFT)
        if _on_canvas(end[0], w, h):
            cv2.circle(out, _fixed(end[0]), 2 * _SCALE, BLACK, -1, cv2.LINE_AA, _SHIFT)

    labels = []         # (priority, text, anchor, outward, colour): measured, nearest first
    for s, mid in zip(report.sections, anchors, strict=True):
        if s.status not in (STATUS_OK, STATUS_CLEAR) or mid is None:
            continue
        outward = mid - centre
        outward /= max(np.linalg.norm(outward), 1e-9)
        if s.status == STATUS_OK:
            piece = _clipped(s.hull_point_px, s.obstacle_point_px, w, h)
            if piece is not None:
                cv2.line(out, _fixed(piece[0]), _fixed(piece[1]), YELLOW, max(1, thickness - 1),
                         cv2.LINE_AA, _SHIFT)
            if _on_canvas(s.obstacle_point_px, w, h):
                cv2.circle(out, _fixed(s.obstacle_point_px), 2 * _SCALE, YELLOW, -1,
                           cv2.LINE_AA, _SHIFT)
        text, colour = section_label(s, report.sensors_contradicted, alarm_m,
                                     section_colour(alarm_distance_m(s), warn_m, alarm_m))
        priority = s.distance_m if s.status == STATUS_OK else np.inf
        labels.append((priority, text, mid + outward * 18 * scale / 0.5, outward, colour))
    labels.sort(key=lambda label: label[0])
    band = int(22 * scale / 0.4)            # the banners' height (draw_banner)
    banners = [(0, 0, w, band)] + ([(0, h - band, w, h)] if footer else [])
    _place_labels(out, [label[1:] for label in labels], scale, banners)

    md = report.min_distance_m
    # the method only when it is not the default (the banner has one line of a 640-px frame)
    method = "" if report.method == "ground_plane" else f"  {report.method}"
    header = (f"{report.vessel}  alt {report.altitude_m:.0f} m  GSD {report.gsd_m_per_px * 100:.1f} cm/px"
              f"{method}  min {'--' if md is None else f'{md:.1f} m'}"
              f"{_pose_note(report.pose_refinement)}")
    draw_banner(out, header)
    if footer:
        draw_banner(out, footer, WHITE, bottom=True)
    return out


#: a clear band seen out to less than this (it leaves the picture at the hull) says nothing
UNSEEN_BELOW_M = 0.05


def section_label(section, sensors_contradicted: bool, alarm_m: float, ok_colour: tuple
                  ) -> tuple[str, tuple]:
    """A measured section's label and its colour (``ok_colour`` for an ``ok`` one):
    ``3.2+-0.4m`` (OpenCV's Hershey fonts have no "±"; ``!`` where it touches), ``??`` read
    with a pose the image contradicts, ``>12.5m`` where nothing solid lies in the band as far
    as it was seen, ``unseen`` where the band leaves the picture at the hull (a reach of
    ``>0.0m`` would read like a clearance), ``hid 2.1m`` (after the reach seen) where the
    vessel itself hides its band's water out to at least ``alarm_m``, and ``clear`` where the
    band was seen to the horizon."""
    s = section
    if s.status == STATUS_OK:
        spread = "" if s.sigma_m is None else f"+-{s.sigma_m:.1f}"
        return f"{s.distance_m:.1f}{spread}m" + ("!" if s.contact else ""), ok_colour
    if sensors_contradicted:            # read with a pose known to be wrong
        return "??", WHITE
    if s.hidden_to_m is not None and s.hidden_to_m >= alarm_m:
        # the vessel itself hides its band's water out to there (a deckhouse, obliquely)
        seen = f">{s.clear_to_m:.1f}m " if s.clear_to_m and s.clear_to_m >= UNSEEN_BELOW_M else ""
        return f"{seen}hid {s.hidden_to_m:.1f}m", WHITE
    if s.clear_to_m is not None:        # nothing solid as far as its band was seen
        return ("unseen" if s.clear_to_m < UNSEEN_BELOW_M else f">{s.clear_to_m:.1f}m"), WHITE
    return "clear", WHITE               # seen to the horizon


def _pose_note(refinement: dict | None) -> str:
    """``pose +1.3 m 0.8 deg`` (and ``h -0.9 m`` when the height moved by 5 cm or more)
    when the pose was refined, ``pose: sensors`` when the alignment was not trusted,
    nothing when it was off; a pose carried from earlier frames' images
    (:mod:`harborsight.flight.pose_carry`) says ``carried`` in place of the sensors."""
    if not refinement or refinement.get("reason") == "off":
        return ""
    if refinement.get("sensors_contradicted"):
        return "  POSE CONTRADICTED: distances untrusted"
    carried = bool(refinement.get("carried_from"))
    if refinement.get("applied"):
        shift = float(np.hypot(*refinement["shift_m"]))
        note = f"  pose {shift:+.1f} m {refinement['rotation_deg']:+.1f} deg"
        height_m = float(refinement.get("height_change_m") or 0.0)
        return (note + (f" h {height_m:+.1f} m" if abs(height_m) >= 0.05 else "")
                + (" (carried)" if carried else ""))
    return "  pose: carried" if carried else "  pose: sensors"


def _label_anchor(section, end: np.ndarray, w: int, h: int) -> np.ndarray | None:
    """Where a section's label hangs: the middle of its visible ends (kept within a frame's
    width of the picture), else, for a section with one end behind the camera, its hull
    point; None if neither is known."""
    finite = end[np.isfinite(end).all(axis=1)]
    if len(finite) == 2:
        point = finite.mean(axis=0)
    elif section.hull_point_px is not None and np.isfinite(section.hull_point_px).all():
        point = np.asarray(section.hull_point_px, float)
    elif len(finite):
        point = finite[0]
    else:
        return None
    return np.clip(point, [-w, -h], [2 * w, 2 * h])


def draw_banner(image_bgr: np.ndarray, text: str, colour=WHITE, bottom: bool = False) -> None:
    """A black band with one line of text across the top (or bottom) of the image, in place."""
    h, w = image_bgr.shape[:2]
    scale = max(0.35, min(w, h) / 900.0)
    band = int(22 * scale / 0.4)
    top = h - band if bottom else 0
    cv2.rectangle(image_bgr, (0, top), (w, top + band), BLACK, -1)
    cv2.putText(image_bgr, text, (6, top + int(16 * scale / 0.4)), cv2.FONT_HERSHEY_SIMPLEX,
                scale, colour, 1, cv2.LINE_AA)
