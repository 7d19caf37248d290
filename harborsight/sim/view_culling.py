"""Which scene objects can show in a frame at all: the rest need not be built in Blender.

A marina scene holds 100-250 objects (1,000 Blender objects with their parts) laid out far
beyond the camera's view, and building and ray-tracing them is most of a marina frame's
render time. An object can change the frame's pixels in three ways, each bounded by points
that are projected with the frame's camera (lens included):

* **seen directly**: the 8 corners of its axis-aligned box;
* **its shadow**: each box corner above the water ``p`` (``p_z > 0``) casts along the light's
  direction ``s`` (``s_z < 0``) to the water plane at ``p - (p_z / s_z) s``. The sun is a
  disk: ``s`` is taken at the disk's centre and at its edge toward the horizon (the longest
  shadow) and to either side in azimuth, so the penumbra is inside. A shadow that falls on
  another object lies between the object and its shadow on the water, inside the same hull;
* **its reflection** in the water: a mirror at ``z = 0`` shows the corner ``(x, y, -z)``.

The object is kept when the bounding box of all those projections, grown by
:data:`MARGIN` of the image's width (the waves tilt the mirror; soft edges), overlaps the image, or when any
point cannot be projected (behind the camera or past the lens model's edge: kept, to be
safe). What is left out can still reach the frame as diffuse light bounced off it (Cycles'
one diffuse bounce), so the RGB of a frame changes by a few grey levels at most where such an
object stood near the edge of the view; the labels, instances and ground truth do not change
(the ground truth is computed from the whole scene, and the ray-cast check of the labels
still traces every object, so an object left out by mistake would fail it).
"""

from __future__ import annotations

import math

import numpy as np

from harborsight.sim.scene import HarbourScene, SceneObject

#: how far outside the image a projection may end and still count as in view, as a share of
#: the image's width (26 px at 640)
MARGIN = 0.04
_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)


def light_directions(elevation_deg: float, azimuth_deg: float, angle_deg: float) -> np.ndarray:
    """Unit directions ``(4, 3)`` the sunlight travels (ENU, downward): from the disk's centre,
    from its lowest edge and from its two sides (azimuth clockwise from north)."""
    half = angle_deg / 2.0
    directions = []
    for el, az in ((elevation_deg, azimuth_deg), (elevation_deg - half, azimuth_deg),
                   (elevation_deg, azimuth_deg - half), (elevation_deg, azimuth_deg + half)):
        el_r, az_r = math.radians(max(el, 1.0)), math.radians(az)
        directions.append((-math.sin(az_r) * math.cos(el_r), -math.cos(az_r) * math.cos(el_r),
                           -math.sin(el_r)))
    return np.array(directions)


def object_reach_points(obj: SceneObject, light: np.ndarray) -> np.ndarray:
    """World points ``(N, 3)`` whose projections bound where ``obj``, its shadows along each
    of ``light``'s directions and its reflection can appear (module docstring)."""
    vertices = np.vstack([np.asarray(part.mesh.vertices) for part in obj.parts])
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    box = low + _CORNERS * (high - low)
    above = box[box[:, 2] > 0.0]
    shadows = [above - (above[:, 2] / s[2])[:, None] * s for s in light] if len(above) else []
    return np.vstack([box, *shadows, box * np.array([1.0, 1.0, -1.0])])


def objects_in_view(scene: HarbourScene, sun_angle_deg: float) -> list[SceneObject]:
    """The objects of ``scene`` that can change its frame (module docstring), in scene order;
    the vessel of interest (``objects[0]``) always."""
    camera = scene.geometry().camera
    env = scene.environment
    light = light_directions(env.sun_elevation_deg, env.sun_azimuth_deg, sun_angle_deg)
    width, height = scene.intrinsics.width, scene.intrinsics.height
    margin = MARGIN * width
    kept = []
    for i, obj in enumerate(scene.objects):
        if i == 0:
            kept.append(obj)
            continue
        uv, _ = camera.project(object_reach_points(obj, light))
        if not np.isfinite(uv).all():
            kept.append(obj)                       # cannot tell: keep it
            continue
        (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
        if (u1 >= -0.5 - margin and v1 >= -0.5 - margin
                and u0 <= width - 0.5 + margin and v0 <= height - 0.5 + margin):
            kept.append(obj)
    return kept
