"""Render a :class:`~harborsight.sim.scene.HarbourScene` with Blender (bpy 4.5, Cycles, CPU).

Two renders per frame share one Blender scene:

1. **RGB**: Principled materials with procedural texture, a Nishita sky and a sun lamp
   (shadows), water from the Ocean modifier (waves, foam attribute) with a ripple bump map,
   Cycles path tracing with the OpenImageDenoise denoiser.
2. **Ids**: the same geometry with every material overridden by an emission of the object's
   colour, which encodes its instance id (``R = id & 255``, ``G = id >> 8``, ``B = 1``, in
   0..255 steps), one sample per pixel through a 0.01 px box filter (the pixel centre, as
   OpenCV's convention has it), the ``Raw`` view transform and no dithering, so the PNG holds
   the exact ids. Background pixels are transparent (id ``NO_HIT``).

Camera: the OpenCV intrinsics map to a Blender camera with a horizontal sensor fit,
``lens = fx · sensor_width / width`` and shifts ``shift_x = ((W−1)/2 − cx)/W``,
``shift_y = (cy − (H−1)/2)/W``; the Blender camera looks along its −z with +y up, so
``R_W<-blender = R_W<-C · diag(1, −1, −1)``.

The ray-cast check in :mod:`harborsight.sim.raycast` verifies all of this independently.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.sim.scene import NO_HIT, Environment, HarbourScene, Material, SceneObject


@dataclass(frozen=True)
class RenderPreset:
    """Quality knobs of one render preset (the image size comes from the camera)."""

    name: str
    width: int
    height: int
    samples: int
    denoise: bool
    max_bounces: int
    ocean_resolution: int       # Ocean modifier resolution (grid cells per tile side = r^2)
    ocean_tile_m: float = 50.0


PRESETS = {
    "tiny": RenderPreset("tiny", 64, 36, 2, False, 2, 4),
    "default": RenderPreset("default", 640, 360, 8, True, 3, 7),
    "high": RenderPreset("high", 1280, 720, 32, True, 6, 9),
}


def sun_angle_deg(environment: Environment) -> float:
    """The sun disk's angular diameter: a clear sun's 1.5 degrees, or 15 under overcast (a
    weak sun), for soft shadows."""
    return 1.5 if environment.sun_strength > 2 else 15.0


@dataclass
class RenderOutput:
    image_bgr: np.ndarray          # uint8 (H, W, 3), before the post effects
    instances: np.ndarray          # uint16 (H, W): instance id, 0 water, NO_HIT background
    ocean_triangles: np.ndarray    # (n, 3, 3) world metres: the water surface Blender rendered


def decode_id_image(rgba: np.ndarray) -> np.ndarray:
    """Ids from the id render (RGBA uint8, as cv2 reads it: BGRA)."""
    b, g, r, a = (rgba[..., i].astype(np.uint32) for i in range(4))
    ids = (r | (g << 8)).astype(np.uint32)
    ids[(a < 128) | (b < 128)] = NO_HIT
    return ids.astype(np.uint16)


@contextlib.contextmanager
def _silenced_stdout():
    """Blender prints a line per render step on the C-level stdout: send it to /dev/null."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def _id_colour(instance_id: int) -> tuple[float, float, float, float]:
    return ((instance_id & 255) / 255.0, (instance_id >> 8) / 255.0, 1.0, 1.0)


class BlenderRenderer:
    """One Blender session rendering many scenes (build, render RGB, render ids, clear)."""

    def __init__(self, preset: RenderPreset, threads: int | None = None) -> None:
        import bpy  # only the simulator needs Blender

        self.bpy = bpy
        self.preset = preset
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        if threads:
            scene.render.threads_mode = "FIXED"
            scene.render.threads = threads
        scene.render.image_settings.file_format = "PNG"
        scene.render.image_settings.compression = 0
        scene.render.dither_intensity = 0.0
        scene.render.use_persistent_data = False
        scene.cycles.seed = 0
        self.scene = scene
        self.id_material = self._make_id_material()
        self.id_world = bpy.data.worlds.new("harborsight-ids")
        self.id_world.use_nodes = False
        self.id_world.color = (0.0, 0.0, 0.0)
        self.id_world.use_fake_user = True
        self.sky_world = None

    # ------------------------------------------------------------------ building

    def _clear(self) -> None:
        """Remove the last scene's data blocks in one batch (one at a time is quadratic in
        their number: 4.6 s for a marina's thousand objects)."""
        bpy = self.bpy
        doomed = list(bpy.data.objects)
        for collection in (bpy.data.meshes, bpy.data.materials, bpy.data.lights,
                           bpy.data.cameras, bpy.data.worlds):
            doomed += [block for block in collection
                       if block is not self.id_material and block is not self.id_world]
        bpy.data.batch_remove(doomed)

    def _make_id_material(self):
        mat = self.bpy.data.materials.new("harborsight-ids")
        mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        nodes.clear()
        info = nodes.new("ShaderNodeObjectInfo")
        emission = nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 1.0
        out = nodes.new("ShaderNodeOutputMaterial")
        links.new(info.outputs["Color"], emission.inputs["Color"])
        links.new(emission.outputs["Emission"], out.inputs["Surface"])
        mat.use_fake_user = True
        return mat

    def _material(self, name: str, spec: Material):
        mat = self.bpy.data.materials.new(name)
        mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        bsdf = nodes["Principled BSDF"]
        bsdf.inputs["Roughness"].default_value = spec.roughness
        bsdf.inputs["Metallic"].default_value = spec.metallic
        coords = nodes.new("ShaderNodeTexCoord")
        if spec.pattern == "planks":
            # boards across the object's x: a banded wave texture (one band a board, about
            # 0.15 m at texture_scale 3), its bands' edges darkened like the gaps between boards
            noise = nodes.new("ShaderNodeTexWave")
            noise.wave_type = "BANDS"
            noise.bands_direction = "X"
            noise.wave_profile = "SAW"
            noise.inputs["Scale"].default_value = spec.texture_scale * 0.35
            noise.inputs["Distortion"].default_value = 0.5
            noise.inputs["Detail"].default_value = 1.0
        else:
            noise = nodes.new("ShaderNodeTexNoise")
            noise.inputs["Scale"].default_value = spec.texture_scale
            noise.inputs["Detail"].default_value = 2.0
        links.new(coords.outputs["Object"], noise.inputs["Vector"])
        ramp = nodes.new("ShaderNodeMix")
        ramp.data_type = "RGBA"
        lo = [max(0.0, c * (1.0 - spec.texture)) for c in spec.rgb]
        hi = [min(1.0, c * (1.0 + spec.texture)) for c in spec.rgb]
        ramp.inputs["A"].default_value = (*lo, 1.0)
        ramp.inputs["B"].default_value = (*hi, 1.0)
        links.new(noise.outputs["Fac"], ramp.inputs["Factor"])
        links.new(ramp.outputs["Result"], bsdf.inputs["Base Color"])
        return mat

    def _add_scene_object(self, obj: SceneObject, materials: dict) -> None:
        """One Blender object for a scene object: its parts joined into one mesh (world
        coordinates, so that the textures' object coordinates are the world's as before), a
        material slot for each material they use. A marina holds a thousand parts; one
        object for each cost 0.2-0.5 s a frame in Cycles' scene sync (the pixels are the
        same; docs/results.md)."""
        if not obj.parts:
            return
        bpy = self.bpy
        slots: dict[str, int] = {}
        vertices, faces, slot_of_face = [], [], []
        n_vertices = 0
        for part in obj.parts:
            part_vertices, part_faces = np.asarray(part.mesh.vertices), np.asarray(part.mesh.faces)
            vertices.append(part_vertices)
            faces.append(part_faces + n_vertices)
            slot_of_face.append(np.full(len(part_faces), slots.setdefault(part.material, len(slots))))
            n_vertices += len(part_vertices)
        mesh = bpy.data.meshes.new(obj.name)
        mesh.from_pydata(np.vstack(vertices).tolist(), [], np.vstack(faces).tolist())
        for key in slots:                                # in slot order (dicts keep it)
            mesh.materials.append(materials[key])
        mesh.polygons.foreach_set("material_index", np.concatenate(slot_of_face).astype(np.int32))
        blender_obj = bpy.data.objects.new(obj.name, mesh)
        blender_obj.color = _id_colour(obj.instance_id)
        self.scene.collection.objects.link(blender_obj)

    def _water(self, scene: HarbourScene, centre_xy: np.ndarray, half_extent_m: float):
        bpy, env, preset = self.bpy, scene.environment, self.preset
        mesh = bpy.data.meshes.new("ocean")
        obj = bpy.data.objects.new("ocean", mesh)
        self.scene.collection.objects.link(obj)
        tile = preset.ocean_tile_m
        repeat = max(1, math.ceil(2 * half_extent_m / tile))
        ocean = obj.modifiers.new("ocean", "OCEAN")
        ocean.geometry_mode = "GENERATE"
        ocean.resolution = preset.ocean_resolution
        ocean.spatial_size = int(tile)
        ocean.size = 1.0
        ocean.repeat_x = ocean.repeat_y = repeat
        ocean.wave_scale = env.wave_scale
        ocean.wind_velocity = env.wind_mps
        ocean.choppiness = env.choppiness
        ocean.random_seed = env.ocean_seed
        ocean.use_foam = True
        ocean.foam_layer_name = "foam"
        ocean.foam_coverage = env.foam_coverage
        # generated tiles span [-tile/2, (repeat - 1/2) tile]: centre them on the view
        if scene.water_anchor_xy is not None:
            # a sequence: whole tiles from the harbour's anchor, so the waves stay with the
            # harbour as the vessel moves, and the ocean's time runs
            anchor = np.asarray(scene.water_anchor_xy, float)
            repeat += 1
            centre_xy = anchor + tile * np.round((np.asarray(centre_xy) - anchor) / tile)
            ocean.time = 1.0 + scene.water_time_s
            ocean.repeat_x = ocean.repeat_y = repeat
        obj.location = (centre_xy[0] - (repeat - 1) * tile / 2, centre_xy[1] - (repeat - 1) * tile / 2, 0)
        obj.color = _id_colour(0)

        mat = bpy.data.materials.new("water")
        mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        bsdf = nodes["Principled BSDF"]
        bsdf.inputs["Roughness"].default_value = env.water_roughness
        bsdf.inputs["IOR"].default_value = 1.333
        foam = nodes.new("ShaderNodeAttribute")
        foam.attribute_name = "foam"
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.inputs["A"].default_value = (*env.water_rgb, 1.0)
        mix.inputs["B"].default_value = (*(0.6 * c for c in (0.75, 0.77, 0.77)), 1.0)
        clamp = nodes.new("ShaderNodeMapRange")
        clamp.inputs["From Min"].default_value = 0.5
        clamp.inputs["From Max"].default_value = 1.0
        links.new(foam.outputs["Fac"], clamp.inputs["Value"])
        links.new(clamp.outputs["Result"], mix.inputs["Factor"])
        links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
        ripples = nodes.new("ShaderNodeTexNoise")
        ripples.inputs["Scale"].default_value = 1.5
        ripples.inputs["Detail"].default_value = 2.0
        coords = nodes.new("ShaderNodeTexCoord")
        links.new(coords.outputs["Object"], ripples.inputs["Vector"])
        bump = nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = env.ripple_strength
        bump.inputs["Distance"].default_value = 0.05
        links.new(ripples.outputs["Fac"], bump.inputs["Height"])
        links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
        obj.data.materials.append(mat)
        return obj

    def _world_and_sun(self, scene: HarbourScene) -> None:
        from mathutils import Vector

        bpy, env = self.bpy, scene.environment
        world = bpy.data.worlds.new("sky")
        world.use_nodes = True
        nodes, links = world.node_tree.nodes, world.node_tree.links
        # Hosek-Wilkie is analytic (Nishita bakes a texture: 0.3 s a frame); no importance
        # map either (1.6 s at 640x360): from 30-150 m up the sky is seen in reflections only
        world.cycles.sampling_method = "NONE"
        el, az = math.radians(env.sun_elevation_deg), math.radians(env.sun_azimuth_deg)
        towards_sun = Vector((math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)))
        sky = nodes.new("ShaderNodeTexSky")
        sky.sky_type = "HOSEK_WILKIE"
        sky.sun_direction = towards_sun
        sky.turbidity = env.sky_turbidity
        sky.ground_albedo = 0.3
        background = nodes["Background"]
        background.inputs["Strength"].default_value = 0.12 if env.sun_strength > 2.5 else 0.3
        links.new(sky.outputs["Color"], background.inputs["Color"])
        self.scene.world = world
        self.sky_world = world

        sun = bpy.data.lights.new("sun", "SUN")
        sun.energy = env.sun_strength
        sun.angle = math.radians(sun_angle_deg(env))
        obj = bpy.data.objects.new("sun", sun)
        obj.rotation_euler = towards_sun.to_track_quat("Z", "Y").to_euler()
        self.scene.collection.objects.link(obj)

    def _camera(self, scene: HarbourScene) -> None:
        from mathutils import Matrix

        bpy, intr = self.bpy, scene.intrinsics
        if abs(intr.fx - intr.fy) > 1e-6 * intr.fx:
            raise ValueError("the simulator needs square pixels (fx == fy)")
        cam = bpy.data.cameras.new("camera")
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = 36.0
        cam.lens = intr.fx * cam.sensor_width / intr.width
        cam.shift_x = ((intr.width - 1) / 2 - intr.cx) / intr.width
        cam.shift_y = (intr.cy - (intr.height - 1) / 2) / intr.width
        cam.clip_start = 0.5
        cam.clip_end = 20_000.0
        obj = bpy.data.objects.new("camera", cam)
        geometry = scene.geometry()
        r_wb = geometry.camera.world_from_camera @ np.diag([1.0, -1.0, -1.0])
        pose = np.eye(4)
        pose[:3, :3] = r_wb
        pose[:3, 3] = geometry.camera.position_enu
        obj.matrix_world = Matrix(pose.tolist())
        self.scene.collection.objects.link(obj)
        self.scene.camera = obj
        render = self.scene.render
        render.resolution_x, render.resolution_y = intr.width, intr.height
        render.resolution_percentage = 100
        render.pixel_aspect_x = render.pixel_aspect_y = 1.0

    def build(self, scene: HarbourScene, cull: bool = True) -> None:
        """Replace the Blender scene's contents with ``scene``; with ``cull``, only the
        objects that can change the frame (:mod:`harborsight.sim.view_culling`)."""
        from harborsight.sim.view_culling import objects_in_view

        self._clear()
        objects = objects_in_view(scene, sun_angle_deg(scene.environment)) if cull else scene.objects
        used = {part.material for obj in objects for part in obj.parts}
        materials = {key: self._material(key, spec) for key, spec in scene.materials.items()
                     if key in used or not cull}
        for obj in objects:
            self._add_scene_object(obj, materials)
        geometry = scene.geometry()
        intr = scene.intrinsics
        corners = np.array([[0, 0], [intr.width - 1, 0], [intr.width - 1, intr.height - 1],
                            [0, intr.height - 1], [(intr.width - 1) / 2, (intr.height - 1) / 2]])
        ground, valid = geometry.camera.back_project_to_plane(corners)
        ground = ground[valid, :2]
        centre = ground[-1] if valid[-1] else ground.mean(axis=0)
        half_extent = float(np.max(np.abs(ground - centre))) + 30.0
        self._water(scene, centre, half_extent)
        self._world_and_sun(scene)
        self._camera(scene)

    # ------------------------------------------------------------------ rendering

    def _render_to(self, name: str) -> np.ndarray:
        """Render the scene and read back the PNG Blender writes. The file lives in a folder
        made and removed around this one render: render workers are terminated, not closed,
        so a folder kept for the renderer's life was left behind by every worker."""
        with tempfile.TemporaryDirectory(prefix="harborsight-blender-") as folder:
            path = Path(folder) / name
            self.scene.render.filepath = str(path)
            with _silenced_stdout():
                self.bpy.ops.render.render(write_still=True)
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise RuntimeError(f"Blender wrote no image to {path}")
            return image

    def render(self, scene: HarbourScene, cull: bool = True) -> RenderOutput:
        """RGB and instance ids of ``scene`` (``cull``: see :meth:`build`)."""
        self.build(scene, cull)
        s, cycles, preset = self.scene, self.scene.cycles, self.preset
        # RGB
        s.view_layers[0].material_override = None
        s.world = self.sky_world
        s.render.film_transparent = False
        s.view_settings.view_transform = "AgX"
        s.view_settings.look = "None"
        s.view_settings.exposure = scene.environment.exposure_ev
        s.render.image_settings.color_mode = "RGB"
        cycles.samples = preset.samples
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = preset.denoise
        if preset.denoise:
            cycles.denoiser = "OPENIMAGEDENOISE"
            cycles.denoising_quality = "FAST"
            cycles.denoising_prefilter = "FAST"
        cycles.max_bounces = preset.max_bounces
        cycles.diffuse_bounces = 1
        cycles.glossy_bounces = 1
        cycles.transmission_bounces = 0
        cycles.transparent_max_bounces = 0
        cycles.caustics_reflective = cycles.caustics_refractive = False
        cycles.use_light_tree = False  # one sun and an unsampled sky: nothing to choose from
        cycles.pixel_filter_type = "BLACKMAN_HARRIS"
        cycles.filter_width = 1.5
        image = self._render_to("rgb.png")

        # ids: emission of the object colour at the pixel centres, no colour transform
        s.view_layers[0].material_override = self.id_material
        s.world = self.id_world
        s.render.film_transparent = True
        s.view_settings.view_transform = "Raw"
        s.view_settings.exposure = 0.0
        s.render.image_settings.color_mode = "RGBA"
        cycles.samples = 1
        cycles.use_denoising = False
        cycles.max_bounces = 0
        cycles.pixel_filter_type = "BOX"
        cycles.filter_width = 0.01
        ids = decode_id_image(self._render_to("ids.png"))
        return RenderOutput(image[..., :3].copy(), ids, self._ocean_triangles())

    def _ocean_triangles(self) -> np.ndarray:
        bpy = self.bpy
        obj = bpy.data.objects["ocean"]
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = evaluated.to_mesh()
        try:
            mesh.calc_loop_triangles()
            co = np.empty(len(mesh.vertices) * 3)
            mesh.vertices.foreach_get("co", co)
            tris = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int64)
            mesh.loop_triangles.foreach_get("vertices", tris)
        finally:
            evaluated.to_mesh_clear()
        world = np.asarray(obj.matrix_world)
        co = co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
        return co[tris.reshape(-1, 3)]
