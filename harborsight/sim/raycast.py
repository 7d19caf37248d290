"""Independent label check: cast a ray through every pixel centre with trimesh + Embree.

The rays come from harborsight's own camera model built from the frame's metadata (not from
Blender), and hit the scene's own meshes plus the water surface Blender generated. Where the
first hit's instance id matches the id image Blender rendered, the labels, the camera
conventions and the metadata agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from harborsight.errors import HarborsightError
from harborsight.frame import FrameGeometry
from harborsight.sim.scene import NO_HIT, HarbourScene

MIN_AGREEMENT = 0.995


class LabelCheckError(HarborsightError):
    """The rendered labels disagree with the ray-cast beyond tolerance."""


@dataclass
class RayCast:
    instances: np.ndarray       # uint16 (H, W)
    range_m: np.ndarray         # float (H, W), inf where nothing is hit


def scene_triangles(scene: HarbourScene, ocean_triangles: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """All triangles (n, 3, 3) of the scene and each one's instance id."""
    tris, ids = [], []
    for obj in scene.objects:
        for part in obj.parts:
            t = np.asarray(part.mesh.vertices)[np.asarray(part.mesh.faces)]
            tris.append(t)
            ids.append(np.full(len(t), obj.instance_id, np.int64))
    if ocean_triangles is not None and len(ocean_triangles):
        tris.append(ocean_triangles)
        ids.append(np.zeros(len(ocean_triangles), np.int64))
    return np.concatenate(tris), np.concatenate(ids)


def triangles_in_view(geometry: FrameGeometry, triangles: np.ndarray, rays_xy: np.ndarray
                      ) -> np.ndarray:
    """Indices of the triangles ``(n, 3, 3)`` that a pixel's ray may hit, given the rays'
    normalized image coordinates ``(x, y)`` (direction ``(x, y, 1)`` in the camera frame).

    Every ray point ``t (x, y, 1)``, ``t > 0``, has ``X - x_min Z >= 0`` (and likewise for
    ``x_max``, ``y_min``, ``y_max``, and ``Z > 0``): a triangle whose three corners all lie
    on the far side of one of these planes through the camera centre cannot be hit, since
    the half-space is convex. Exact, and independent of the renderer's own culling (which
    keeps shadows and mirror images too), so the check still sees an object the render left
    out by mistake; it spares Embree the marina's boats behind the frame's edges.
    """
    corners = geometry.camera.to_camera_frame(triangles.reshape(-1, 3))
    x, y, z = (corners[:, k].reshape(-1, 3) for k in range(3))
    x_min, y_min = rays_xy.min(axis=0)
    x_max, y_max = rays_xy.max(axis=0)
    outside = ((x - x_min * z < 0).all(axis=1) | (x - x_max * z > 0).all(axis=1)
               | (y - y_min * z < 0).all(axis=1) | (y - y_max * z > 0).all(axis=1)
               | (z <= 0).all(axis=1))
    return np.flatnonzero(~outside)


def ray_cast_ids(geometry: FrameGeometry, triangles: np.ndarray, triangle_ids: np.ndarray
                 ) -> RayCast:
    """First-hit instance id and range for each pixel centre (u, v integer, OpenCV)."""
    intr = geometry.camera.intrinsics
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    uv = np.column_stack((u.ravel(), v.ravel()))
    xy = geometry.camera.normalized_coordinates(uv)
    rays_c = np.column_stack((xy, np.ones(len(xy))))
    dirs = rays_c @ geometry.camera.world_from_camera.T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = np.broadcast_to(geometry.camera.position_enu, dirs.shape).copy()
    shape = (intr.height, intr.width)
    nothing = RayCast(np.full(shape, NO_HIT, np.uint16), np.full(shape, np.inf))
    finite = np.flatnonzero(np.isfinite(dirs).all(axis=1))   # pixels the lens model can invert
    if not len(finite) or not len(triangles):
        return nothing
    seen = triangles_in_view(geometry, triangles, xy[finite])
    if not len(seen):                                        # nothing in view: sky everywhere
        return nothing
    triangles, triangle_ids = triangles[seen], triangle_ids[seen]
    mesh = trimesh.Trimesh(vertices=triangles.reshape(-1, 3),
                           faces=np.arange(len(triangles) * 3).reshape(-1, 3), process=False)
    intersector = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh)
    index_tri, index_ray, locations = intersector.intersects_id(
        origins[finite], dirs[finite], multiple_hits=False, return_locations=True)
    index_ray = finite[index_ray]
    ids = np.full(len(uv), NO_HIT, np.int64)
    ids[index_ray] = triangle_ids[index_tri]
    ranges = np.full(len(uv), np.inf)
    ranges[index_ray] = np.linalg.norm(locations - origins[index_ray], axis=1)
    return RayCast(ids.astype(np.uint16).reshape(shape), ranges.reshape(shape))


def check_labels(rendered_ids: np.ndarray, cast: RayCast, source: str,
                 min_agreement: float = MIN_AGREEMENT) -> float:
    """Share of pixels whose rendered id equals the ray-cast id; raises below the minimum."""
    agreement = float(np.mean(rendered_ids == cast.instances))
    if agreement < min_agreement:
        raise LabelCheckError(
            f"{source}: rendered instance ids agree with the ray-cast on only "
            f"{100 * agreement:.2f} % of pixels (need {100 * min_agreement:.1f} %)")
    return agreement
