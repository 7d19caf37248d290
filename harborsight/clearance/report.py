"""``harborsight.report/1``: the clearance of every hull section in one frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harborsight.files import strict_json, write_text_atomic

REPORT_SCHEMA = "harborsight.report/1"

STATUS_OK = "ok"
STATUS_CLEAR = "clear"            # in view, no obstacle inside its band within the image
STATUS_OUT_OF_VIEW = "out_of_view"


def _round_list(values, digits: int) -> list[float] | None:
    if values is None:
        return None
    return [round(float(v), digits) for v in values]


@dataclass
class SectionClearance:
    """One section's result. Pixel coordinates are (u, v); ENU coordinates (e, n) metres."""

    index: int
    status: str
    hull_px: list[list[float]]
    visible_fraction: float
    distance_m: float | None = None
    distance_px: float | None = None
    hull_point_px: list[float] | None = None
    obstacle_point_px: list[float] | None = None
    hull_point_enu: list[float] | None = None
    obstacle_point_enu: list[float] | None = None
    contact: bool = False
    #: an ``ok`` section whose obstacle point lies on the image's border: it may reach closer
    #: out of view
    truncated: bool = False
    #: one standard deviation of distance_m, its frame-to-frame part, and the one-sided 95 %
    #: lower bound (clearance.uncertainty)
    sigma_m: float | None = None
    sigma_random_m: float | None = None
    distance_lower_m: float | None = None
    #: a ``clear`` section: how far out its band was seen, metres from the hull to where the
    #: band first leaves the image (None: to the horizon); nothing solid lies nearer. An
    #: ``ok`` section has it when its band leaves the image nearer than its obstacle, and its
    #: lower bound is then at most this (an obstacle out of view may be nearer)
    clear_to_m: float | None = None
    #: how far out from the hull the band's water is hidden by the vessel itself (a deckhouse
    #: seen obliquely, a flared deck at nadir), metres; None when no more than the pixels'
    #: rounding is. An obstacle wholly inside it cannot be seen; a ``clear`` section all of
    #: whose band in the picture is hidden has ``clear_to_m`` 0
    hidden_to_m: float | None = None
    #: where the obstacle point is the crossing of an obstacle edge with the band's boundary
    #: ray: that edge's direction at it (pixels), for the uncertainty (not in the report)
    crossing_edge_px: list[float] | None = None
    #: the rate (m/s) at which the vessel's own velocity and turn change ``distance_m``, were
    #: the obstacle fixed, and its sigma (:mod:`harborsight.clearance.own_motion`); None
    #: when the frame gives no vessel velocity. In the report as the closing speed it
    #: means, ``own_closing_mps = -own_rate_mps``
    own_rate_mps: float | None = None
    own_rate_sigma_mps: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "hull_px": [_round_list(p, 2) for p in self.hull_px],
            "status": self.status,
            "distance_m": None if self.distance_m is None else round(self.distance_m, 3),
            "distance_px": None if self.distance_px is None else round(self.distance_px, 2),
            "sigma_m": None if self.sigma_m is None else round(self.sigma_m, 3),
            "sigma_random_m": None if self.sigma_random_m is None else round(self.sigma_random_m, 3),
            "distance_lower_m": (None if self.distance_lower_m is None
                                 else round(self.distance_lower_m, 3)),
            "clear_to_m": None if self.clear_to_m is None else round(self.clear_to_m, 3),
            "hidden_to_m": None if self.hidden_to_m is None else round(self.hidden_to_m, 3),
            "hull_point_px": _round_list(self.hull_point_px, 2),
            "obstacle_point_px": _round_list(self.obstacle_point_px, 2),
            "hull_point_enu": _round_list(self.hull_point_enu, 3),
            "obstacle_point_enu": _round_list(self.obstacle_point_enu, 3),
            "own_closing_mps": None if self.own_rate_mps is None else round(-self.own_rate_mps, 3),
            "own_closing_sigma_mps": (None if self.own_rate_sigma_mps is None
                                      else round(self.own_rate_sigma_mps, 3)),
            "contact": self.contact,
            "truncated": self.truncated,
            "visible_fraction": round(self.visible_fraction, 3),
        }


@dataclass
class ClearanceReport:
    image: str
    timestamp: str | None
    altitude_m: float
    gsd_m_per_px: float
    method: str
    sections: list[SectionClearance]
    vessel: str = ""
    enu_origin: dict[str, float] = field(default_factory=dict)
    #: what the pose refinement found (:meth:`PoseRefinement.to_dict`); None: not run
    pose_refinement: dict[str, Any] | None = None
    #: the sensor sigmas the section sigmas were propagated from, and where each came from
    uncertainty: dict[str, Any] | None = None

    @property
    def sensors_contradicted(self) -> bool:
        """The image showed the sensors' pose wrong by more than the refinement may correct
        (:func:`harborsight.clearance.gross_errors.contradicts_sensors`, or the
        whole-image search for the hull), or showed no vessel where the sensors put it and
        nowhere else: the distances were read with a pose the image does not bear out, so
        trackers and alarms leave them out."""
        return bool(self.pose_refinement and self.pose_refinement.get("sensors_contradicted"))

    @property
    def closest_section(self) -> int | None:
        """The ``ok`` section nearest an obstacle; None when there is none, or when the
        image contradicts the sensors' pose (no reading of the frame is trusted)."""
        if self.sensors_contradicted:
            return None
        ok = [s for s in self.sections if s.status == STATUS_OK]
        return min(ok, key=lambda s: s.distance_m).index if ok else None

    @property
    def min_distance_m(self) -> float | None:
        k = self.closest_section
        return None if k is None else self.sections[k].distance_m

    def to_dict(self) -> dict[str, Any]:
        md = self.min_distance_m
        return {
            "schema": REPORT_SCHEMA,
            "image": self.image,
            "timestamp": self.timestamp,
            "vessel": self.vessel,
            "altitude_m": round(self.altitude_m, 3),
            "gsd_m_per_px": round(self.gsd_m_per_px, 5),
            "method": self.method,
            "enu_origin": self.enu_origin,
            "pose_refinement": self.pose_refinement,
            "uncertainty": self.uncertainty,
            "sections": [s.to_dict() for s in self.sections],
            "min_distance_m": None if md is None else round(md, 3),
            "closest_section": self.closest_section,
        }

    def write(self, path: str | Path) -> None:
        write_text_atomic(path, strict_json(self.to_dict(), indent=2) + "\n")
