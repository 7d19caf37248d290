"""The data of a 3-D harbour scene for the Blender simulator (no bpy here).

A :class:`HarbourScene` is plain data: triangle meshes in the world frame W (ENU metres, origin
at the vessel's GPS antenna on the water plane, z up), one material key per part, an instance
id and class per object, the camera pose, and the environment (sun, sky, water, waves, haze).
:mod:`harborsight.sim.layout` and :mod:`harborsight.sim.families` build them,
:mod:`harborsight.sim.blender` turns them into pictures; the same meshes give the ground
truth (vertical footprints, :func:`HarbourScene.ground_truth`) and the ray-cast label check
(:mod:`harborsight.sim.raycast`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
import trimesh
from shapely.geometry import Polygon

from harborsight.geometry.camera import CameraIntrinsics
from harborsight.geometry.geodesy import GeoOrigin
from harborsight.sim.ground_truth import footprint_union, frame_ground_truth
from harborsight.sim.pose import PosedScene
from harborsight.vessel.spec import VesselSpec

WATER, SHIP, OBSTACLE = 0, 1, 2
VESSEL_INSTANCE = 1
#: instance id of pixels that show no scene object (rays that hit nothing; Blender's background)
NO_HIT = 65535


@dataclass(frozen=True)
class Material:
    """A Principled-BSDF material: linear RGB, roughness, and procedural texture strength."""

    rgb: tuple[float, float, float]
    roughness: float = 0.6
    metallic: float = 0.0
    texture: float = 0.15        # amplitude of the noise that varies the colour
    texture_scale: float = 0.5   # noise frequency, per metre
    pattern: str = "noise"       # "noise", or "planks" (wood boards along the object's x)


@dataclass
class Part:
    mesh: trimesh.Trimesh        # world frame W, metres
    material: str


def waterline_crossings(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(k, 2)`` points where the mesh's triangle edges cross the water plane ``z = 0``.

    An edge ``p -> q`` with ``z_p < 0 < z_q`` (or the reverse) crosses at ``p + t (q - p)``,
    ``t = -z_p / (z_q - z_p)``. For a convex part the cut's outline is the convex hull of
    these points (each edge appears once per face that has it; repeats change no hull). The
    same points as trimesh's ``mesh_plane`` gives, without its per-face bookkeeping: a marina
    has about a thousand parts that straddle the water.
    """
    start = vertices[faces.ravel()]
    end = vertices[faces[:, [1, 2, 0]].ravel()]
    z0, z1 = start[:, 2], end[:, 2]
    crossing = ((z0 < 0.0) & (z1 > 0.0)) | ((z0 > 0.0) & (z1 < 0.0))
    p, q = start[crossing], end[crossing]
    t = -p[:, 2] / (q[:, 2] - p[:, 2])
    return p[:, :2] + t[:, None] * (q[:, :2] - p[:, :2])


@dataclass
class SceneObject:
    name: str
    kind: str
    class_id: int
    instance_id: int
    parts: list[Part]
    #: a boat under way: the bearing of its bow, clockwise from north (its wake is painted
    #: astern, :mod:`harborsight.sim.wakes`); None for what lies still
    course_deg: float | None = None
    _footprint: Polygon | None = field(default=None, init=False, repr=False, compare=False)

    def footprint(self) -> Polygon:
        """Vertical projection of the object above the water plane (z >= 0).

        Each part is convex, so its projection is the convex hull of its vertices above
        the water and of its cut by the plane z = 0; the object's is their union. What lies
        under water (the toe of a rubble mound) is neither seen by the camera nor counted.
        """
        if self._footprint is not None:  # parts do not move once placed
            return self._footprint
        clouds = []
        for part in self.parts:
            vertices = np.asarray(part.mesh.vertices)
            points = [vertices[vertices[:, 2] >= 0.0, :2]]
            if vertices[:, 2].min() < 0.0 < vertices[:, 2].max():
                points.append(waterline_crossings(vertices, np.asarray(part.mesh.faces)))
            points = np.vstack(points)
            if len(points) >= 3:
                clouds.append(points)
        polys = []
        if clouds:      # every part's hull in one call (a marina has thousands of parts);
            # a line through the points has their hull, and is made without a Point for each
            which = np.repeat(np.arange(len(clouds)), [len(c) for c in clouds])
            hulls = shapely.convex_hull(shapely.linestrings(np.vstack(clouds), indices=which))
            polys = list(hulls[shapely.get_type_id(hulls) == shapely.GeometryType.POLYGON])
        self._footprint = footprint_union(polys)
        return self._footprint


@dataclass(frozen=True)
class Environment:
    """The domain-randomised look of a frame."""

    sun_elevation_deg: float = 45.0
    sun_azimuth_deg: float = 180.0      # clockwise from north
    sun_strength: float = 3.0
    sky_turbidity: float = 3.0
    water_rgb: tuple[float, float, float] = (0.02, 0.06, 0.07)
    water_roughness: float = 0.08
    wave_scale: float = 0.5             # Ocean modifier amplitude multiplier
    wind_mps: float = 6.0
    choppiness: float = 1.0
    foam_coverage: float = 0.3
    ripple_strength: float = 0.3        # bump of the small ripples
    ocean_seed: int = 0
    haze: float = 0.1                   # share of the airlight veil at 100 m
    haze_rgb: tuple[float, float, float] = (0.75, 0.78, 0.82)
    exposure_ev: float = 0.0
    noise_sigma: float = 2.0            # sensor noise, 8-bit grey levels
    # a consumer drone's camera (harborsight.sim.families); the defaults change nothing
    vignetting: float = 0.0             # brightness lost in the image corners, share
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)   # gains on R, G, B
    jpeg_quality: int | None = None     # re-encoded as a JPEG of this quality
    motion_blur_px: float = 0.0         # length of a straight blur, pixels
    motion_blur_deg: float = 0.0        # its direction in the image, degrees


@dataclass
class HarbourScene(PosedScene):
    """Everything one frame needs: geometry, materials, camera, environment."""

    name: str
    vessel: VesselSpec
    vessel_dir_name: str
    vessel_heading_deg: float
    objects: list[SceneObject]          # the vessel of interest is ``objects[0]``
    materials: dict[str, Material]
    intrinsics: CameraIntrinsics
    uav_enu: np.ndarray
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    environment: Environment
    scenario: str
    gap_m: float | None
    origin: GeoOrigin = field(default_factory=lambda: GeoOrigin(56.1517, 10.2283, 0.0))
    timestamp: str | None = None
    # sequences (harborsight.sim.sequence): where the harbour's water pattern is anchored in
    # W (None: on the view), the ocean's time, and the motion that made this frame
    water_anchor_xy: tuple[float, float] | None = None
    water_time_s: float = 0.0
    sequence: dict | None = None

    @property
    def class_of_instance(self) -> dict[int, int]:
        return {obj.instance_id: obj.class_id for obj in self.objects}

    def obstacle_footprints(self) -> list[Polygon]:
        return [obj.footprint() for obj in self.objects if obj.instance_id != VESSEL_INSTANCE]

    def ground_truth(self) -> dict:
        """design.md ``ground_truth``: per-section exact distances and the true poses."""
        per_section = frame_ground_truth(self.geometry(), self.vessel, self.obstacle_footprints())
        return {
            "sections": per_section,
            "n_sections": len(per_section),
            "vessel_pose": {"lat": self.origin.lat_deg, "lon": self.origin.lon_deg,
                            "heading_deg": self.vessel_heading_deg},
            "uav_enu_m": [float(v) for v in self.uav_enu],
            "scenario": self.scenario,
            "gap_m": self.gap_m,
            **({"sequence": self.sequence} if self.sequence else {}),
        }
