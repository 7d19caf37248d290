"""``harborsight simulate``: render a dataset (design.md layout) with Blender, resumably.

Frame ``i`` of a dataset with seed ``S`` is a pure function of ``(S, i)`` and the parameters:
its scene comes from ``numpy.random.default_rng([S, i])``. A re-run skips frames whose
``frames/NNNNNN.json`` exists (written last, atomically), so an interrupted run resumes and a
larger ``--n`` extends a dataset. Workers are separate processes, each holding one Blender
session; ``--scheduler`` sends chunks of frames to a Dask cluster instead, whose tasks render
in a child process and return the files as bytes (no shared disk needed).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np
import yaml

from harborsight import __version__
from harborsight.errors import HarborsightError, InputError
from harborsight.files import write_bytes_atomic
from harborsight.geometry.geodesy import GeoOrigin
from harborsight.sim.cameras import CAMERA_PRESETS
from harborsight.sim.families import LEISURE_HULLS
from harborsight.sim.layout import (
    FAMILIES,
    LEISURE_FAMILIES,
    LEISURE_LENGTH_M,
    LEISURE_VESSEL_PREFIX,
    SCENARIOS,
    generate_vessel,
    sample_harbour_scene,
)
from harborsight.sim.metering import auto_expose, draw_target_lightness
from harborsight.sim.scene import HarbourScene
from harborsight.sim.wakes import paint_wakes
from harborsight.vessel.spec import VesselSpec, load_vessel_spec

CLASSES = {"0": "water", "1": "ship", "2": "obstacle", "255": "ignore"}
SUBDIRS = ("images", "labels", "instances", "frames")
#: vessels of the pool are drawn from this stream of the dataset seed
VESSEL_STREAM = 2**31 - 1
#: leisure vessels of the pool (the families' vessels of interest) from this stream of the seed
LEISURE_VESSEL_STREAM = 2**31 - 2
#: a frame's wakes are drawn from this stream of (seed, index)
WAKE_STREAM = 6
#: a family frame's metering target is drawn from this stream of (seed, index)
METERING_STREAM = 7
#: a leisure craft's paint (the families' vessel of interest) from this stream of (seed, scene)
LEISURE_PAINT_STREAM = 8
#: whether a marina frame looks along the berths, and where, from this stream of (seed, scene)
BERTH_VIEW_STREAM = 9


@dataclass(frozen=True)
class SimulationConfig:
    """Everything a frame depends on besides its index (stored in ``dataset.json``)."""

    seed: int
    preset: str = "default"
    altitudes_m: tuple[float, ...] = tuple(float(a) for a in range(30, 151, 10))
    camera: str = "dji-mavic3"
    max_tilt_deg: float = 15.0
    vessel_spec: str | None = None        # a user's vessel.yaml (with hull_mesh)
    vessel_pool: int = 6                  # procedural vessels when no spec is given
    scenario: str | None = None           # a scenario, or a comma list cycled by frame index
    split: str | None = None              # put every frame in this split (e.g. test)
    val_fraction: float = 0.1
    origin_lat_lon: tuple[float, float] = (56.1517, 10.2283)
    # flights (harborsight.sim.sequence): frames per scene (0: every frame its own scene),
    # seconds between frames, the vessel's closing speed toward its nearest obstacle
    sequence_frames: int = 0
    frame_interval_s: float = 0.5
    approach_speed_mps: float = 0.5
    # sensor noise of the written frame metadata (sim.pose_noise.PoseNoise fields: gps_m,
    # heading_deg, height_m); None: exact poses. The true pose stays in the ground truth
    pose_noise: dict | None = None
    # build in Blender only the objects that can change the frame (sim.view_culling); the
    # labels are the same either way, the RGB within a few grey levels at a few pixels
    cull_out_of_view: bool = True
    # paint the wakes of boats under way on the rendered water (sim.wakes; labels unchanged)
    wakes: bool = True
    # meter the families' frames as a drone camera does (sim.metering); classic scenes as before
    auto_exposure: bool = True
    # a lake shore or a marina centres on a leisure craft of 6-16 m from a pool of its own
    # (sim.layout.LEISURE_FAMILIES); classic scenes and the other families as before
    leisure_vessels: bool = True
    # some marina frames look along the berths, not at the vessel in the fairway
    # (sim.families.BERTH_VIEW_SHARE); the scene is the same, only the camera's aim moves.
    # Never in a flight (sequence_frames), whose frames must show the berthing vessel
    berth_views: bool = True
    # marinas of 3-6 rows of pontoons a side with few empty berths (sim.families
    # .DENSE_MARINA); off: the sparser marinas of datasets rendered before
    dense_marinas: bool = True

    #: what a parameter added later means for a dataset.json written before it: the
    #: behaviour it was rendered with (not the new default), so that it resumes unchanged
    LEGACY_PARAMETERS: ClassVar[dict] = {"cull_out_of_view": False, "wakes": False,
                                         "auto_exposure": False, "leisure_vessels": False,
                                         "berth_views": False, "dense_marinas": False}

    def validate(self) -> None:
        from harborsight.sim.blender import PRESETS

        if self.preset not in PRESETS:
            raise InputError(None, "--preset", f"unknown preset {self.preset!r}; "
                             f"choose from {', '.join(PRESETS)}")
        if self.camera not in CAMERA_PRESETS:
            raise InputError(None, "--camera", f"unknown camera {self.camera!r}; "
                             f"choose from {', '.join(CAMERA_PRESETS)}")
        if not self.altitudes_m or min(self.altitudes_m) <= 0:
            raise InputError(None, "--altitudes", "need at least one positive altitude")
        if self.sequence_frames < 0 or self.frame_interval_s <= 0 or self.approach_speed_mps < 0:
            raise InputError(None, "--sequence-frames", "need sequence_frames >= 0, "
                             "frame_interval_s > 0 and approach_speed_mps >= 0")
        if self.pose_noise is not None:
            from harborsight.sim.pose_noise import PoseNoise

            try:
                PoseNoise(**self.pose_noise)
            except (TypeError, ValueError) as exc:
                raise InputError(None, "--pose-noise", str(exc)) from None
        if self.scenario:
            parse_scenarios(self.scenario)

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, doc: dict) -> SimulationConfig:
        """The config stored in a ``dataset.json`` (parameters it lacks: as rendered then)."""
        doc = {**cls.LEGACY_PARAMETERS, **doc}
        for key in ("altitudes_m", "origin_lat_lon"):
            if key in doc:
                doc[key] = tuple(doc[key])
        return cls(**doc)

    def intrinsics(self):
        from harborsight.sim.blender import PRESETS

        preset = PRESETS[self.preset]
        return CAMERA_PRESETS[self.camera].intrinsics(preset.width, preset.height)


def parse_altitudes(text: str) -> tuple[float, ...]:
    """``30:150:10`` (start:stop:step, stop included), ``40,80,120`` or ``60``."""
    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            return tuple(float(a) for a in np.arange(start, stop + step / 2, step))
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise InputError(None, "--altitudes", f"expected start:stop:step or a list, got {text!r}") from None


def stem_of(index: int) -> str:
    return f"{index:06d}"


def split_of(config: SimulationConfig, index: int) -> str:
    """``train`` or ``val`` by a low-discrepancy sequence (golden ratio), or the forced split."""
    if config.split:
        return config.split
    if config.sequence_frames:   # a flight's frames stay together
        index //= config.sequence_frames
    return "val" if (index * 0.6180339887498949) % 1.0 < config.val_fraction else "train"


# ---------------------------------------------------------------------------- vessels


def _copy_vessel_spec(src: Path, dst: Path) -> None:
    """Copy a vessel spec and its mesh, nothing else, into ``dst`` (``vessel.yaml`` written
    last, so a half-done copy is redone). A mesh named by a relative path inside the spec's
    folder keeps that path; any other goes beside the spec and the copy names it so."""
    doc = yaml.safe_load(src.read_text())
    mesh_src = (src.parent / str(doc["hull_mesh"])).resolve()
    try:
        mesh_rel = mesh_src.relative_to(src.parent.resolve())
    except ValueError:
        mesh_rel = Path(mesh_src.name)
    (dst / mesh_rel).parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(mesh_src, dst / mesh_rel)
    if mesh_rel.as_posix() == str(doc["hull_mesh"]):
        text = src.read_text()   # unchanged, comments and all
    else:
        text = yaml.safe_dump({**doc, "hull_mesh": mesh_rel.as_posix()}, sort_keys=False)
    write_bytes_atomic(dst / "vessel.yaml", text.encode())


def prepare_vessels(out_dir: Path, config: SimulationConfig) -> dict[str, Path]:
    """Write the vessel(s) under ``vessels/`` (idempotent); returns name -> vessel.yaml."""
    vessels_dir = out_dir / "vessels"
    if config.vessel_spec:
        src = Path(config.vessel_spec)
        if not src.is_absolute():  # relative to the dataset (a vessel shipped inside it)
            src = out_dir / src
        spec = load_vessel_spec(src)
        if spec.mesh is None:
            raise InputError(src, "hull_mesh", "the simulator renders the vessel's mesh: give one")
        dst = vessels_dir / spec.name
        if not (dst / "vessel.yaml").is_file():
            _copy_vessel_spec(src, dst)
        return {spec.name: dst / "vessel.yaml"}
    paths = {}
    for k in range(config.vessel_pool):
        name = f"sim-vessel-{k:02d}"
        target = vessels_dir / name
        if not (target / "vessel.yaml").is_file():
            generate_vessel(np.random.default_rng([config.seed, VESSEL_STREAM, k]), name, target)
        paths[name] = target / "vessel.yaml"
    if config.leisure_vessels and _draws_leisure_family(config):
        for k in range(config.vessel_pool):
            name = f"{LEISURE_VESSEL_PREFIX}{k:02d}"
            target = vessels_dir / name
            if not (target / "vessel.yaml").is_file():
                generate_vessel(np.random.default_rng([config.seed, LEISURE_VESSEL_STREAM, k]),
                                name, target, LEISURE_LENGTH_M, LEISURE_HULLS)
            paths[name] = target / "vessel.yaml"
    return paths


def _draws_leisure_family(config: SimulationConfig) -> bool:
    """Whether any scene of the config can be a family that centres on a leisure craft."""
    if not config.scenario:
        return False
    names, weights = parse_scenarios(config.scenario)
    weights = weights or [1.0] * len(names)
    return any(n in LEISURE_FAMILIES and w > 0 for n, w in zip(names, weights, strict=True))


def parse_scenarios(text: str) -> tuple[list[str], list[float] | None]:
    """``--scenario``: names cycled by frame index (``lakeshore,marina``), or names with
    weights to draw from (``lakeshore=0.4,marina=0.4,alongside=0.2``; normalised)."""
    names, weights = [], []
    known = [*SCENARIOS, *FAMILIES]
    for item in text.split(","):
        name, _, weight = item.strip().partition("=")
        if name not in known:
            raise InputError(None, "--scenario", f"unknown scenario {name!r}; choose from "
                             f"{', '.join(known)}")
        names.append(name)
        if weight:
            try:
                weights.append(float(weight))
            except ValueError:
                weights.append(float("nan"))
            if not (math.isfinite(weights[-1]) and weights[-1] >= 0):
                raise InputError(None, "--scenario", f"the weight of {name} is {weight!r}: "
                                 "need a number of 0 or more")
    if weights and len(weights) != len(names):
        raise InputError(None, "--scenario", "give every scenario a weight (name=weight), or none")
    if weights and sum(weights) <= 0:
        raise InputError(None, "--scenario", "the weights add up to 0")
    return names, ([w / sum(weights) for w in weights] if weights else None)


def scenario_of(config: SimulationConfig, index: int) -> str | None:
    """The scenario of scene ``index``: a comma list cycles; with weights it is drawn from
    its own stream of (seed, index), so the scene's other draws are those of a forced one;
    None: drawn among the classic five."""
    if not config.scenario:
        return None
    names, weights = parse_scenarios(config.scenario)
    if weights is None:
        return names[index % len(names)]
    rng = np.random.default_rng([config.seed, index, 5])
    return names[int(rng.choice(len(names), p=weights))]


def plan_frame(config: SimulationConfig, index: int, vessels: dict[str, VesselSpec]
               ) -> HarbourScene:
    """The scene of frame ``index``: a pure function of the seed, the index and the config.
    In a flight (``sequence_frames`` > 0) frames ``i·n .. i·n + n - 1`` share scene ``i``
    and follow its vessel's berthing (:mod:`harborsight.sim.sequence`)."""
    scene_index, step = index, 0
    if config.sequence_frames:
        scene_index, step = divmod(index, config.sequence_frames)
    rng = np.random.default_rng([config.seed, scene_index])
    scenario = scenario_of(config, scene_index)
    # the pools apart (a user's vessel is the only one, whatever its name)
    pooled = config.vessel_spec is None
    leisure = sorted(n for n in vessels if pooled and n.startswith(LEISURE_VESSEL_PREFIX))
    classic = sorted(n for n in vessels if n not in leisure)
    use_leisure = bool(leisure) and config.leisure_vessels and scenario in LEISURE_FAMILIES
    names = leisure if use_leisure else classic
    name = names[int(rng.integers(len(names)))]
    altitude = config.altitudes_m[scene_index % len(config.altitudes_m)]
    scene = sample_harbour_scene(
        vessels[name], name, rng, altitude_m=altitude, intrinsics=config.intrinsics(),
        max_tilt_deg=config.max_tilt_deg, scenario=scenario, name=stem_of(index),
        leisure_paint=(np.random.default_rng([config.seed, scene_index, LEISURE_PAINT_STREAM])
                       if use_leisure else None),
        berth_view_rng=(np.random.default_rng([config.seed, scene_index, BERTH_VIEW_STREAM])
                        if config.berth_views and scenario == "marina" and not config.sequence_frames
                        else None),
        dense_marinas=config.dense_marinas)
    scene.origin = GeoOrigin(*config.origin_lat_lon, 0.0)
    if config.sequence_frames:
        from harborsight.sim.sequence import sequence_frame

        scene = sequence_frame(scene, scene_index, step, config.frame_interval_s,
                               config.approach_speed_mps,
                               np.random.default_rng([config.seed, scene_index, step, 3]),
                               n_frames=config.sequence_frames)
    return scene


# ---------------------------------------------------------------------------- one frame


def apply_camera_effects(image_bgr: np.ndarray, range_m: np.ndarray, scene: HarbourScene,
                         rng: np.random.Generator, target_lightness: float | None = None
                         ) -> tuple[np.ndarray, float | None]:
    """Airlight haze by range, the consumer camera's optics and processing, its metering
    (``target_lightness``: mean L* to meter to, :mod:`harborsight.sim.metering`; None: the
    render's own exposure) and sensor noise. Returns the image and the metering's gain (EV;
    None when not metered).

    Haze: ``I' = I·t + A·(1 − t)`` with transmission ``t = (1 − haze)^(range / 100 m)``
    (Koschmieder), ``A`` the haze colour; noise: Gaussian, ``noise_sigma`` grey levels.
    """
    env = scene.environment
    t = np.power(1.0 - env.haze, np.minimum(range_m, 2_000.0) / 100.0)[..., None]
    airlight = 255.0 * np.array(env.haze_rgb[::-1])
    out = image_bgr.astype(np.float32) * t + airlight * (1.0 - t)
    out = _consumer_camera(out, env)
    gain_ev = None
    if target_lightness is not None:
        out, gain_ev = auto_expose(np.clip(out, 0.0, 255.0), target_lightness)
    out += rng.normal(0.0, env.noise_sigma, out.shape)
    out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    if env.jpeg_quality is not None:
        _, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(env.jpeg_quality)])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out, gain_ev


def _consumer_camera(image: np.ndarray, env) -> np.ndarray:
    """Motion blur (a line kernel of ``motion_blur_px`` at ``motion_blur_deg``), white balance
    gains, and vignetting ``1 - v·r²`` with r the distance from the centre over the half
    diagonal. The classic scenes' defaults leave the image as it is."""
    if env.motion_blur_px >= 1.0:
        size = math.ceil(env.motion_blur_px) | 1
        kernel = np.zeros((size, size), np.float32)
        c, a = size // 2, math.radians(env.motion_blur_deg)
        half = env.motion_blur_px / 2
        cv2.line(kernel, (round(c - half * math.cos(a)), round(c - half * math.sin(a))),
                 (round(c + half * math.cos(a)), round(c + half * math.sin(a))), 1.0, 1, cv2.LINE_AA)
        image = cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)
    if tuple(env.white_balance) != (1.0, 1.0, 1.0):
        image = image * np.array(env.white_balance[::-1], np.float32)     # BGR
    if env.vignetting > 0:
        h, w = image.shape[:2]
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
        image = image * (1.0 - env.vignetting * r2)[..., None]
    return image


def class_mask(instances: np.ndarray, class_of_instance: dict[int, int]) -> np.ndarray:
    """Class labels (design.md) from instance ids; unknown ids and the sky are ``255``."""
    lookup = np.full(65536, 255, np.uint8)
    lookup[0] = 0
    for instance, cls in class_of_instance.items():
        lookup[instance] = cls
    return lookup[instances]


def _encode_png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


@dataclass
class FrameResult:
    index: int
    seconds: float
    label_agreement: float | None = None
    scenario: str | None = None
    error: str | None = None
    files: dict[str, bytes] = field(default_factory=dict, repr=False)


class FrameRenderer:
    """Renders frames of one dataset in this process (one Blender session)."""

    def __init__(self, out_dir: Path, config: SimulationConfig, threads: int | None = None) -> None:
        from harborsight.sim.blender import PRESETS, BlenderRenderer

        self.out_dir = out_dir
        self.config = config
        # the vessels were written by simulate() (or shipped with a Dask task)
        paths = sorted((out_dir / "vessels").glob("*/vessel.yaml"))
        if not paths:
            raise InputError(out_dir / "vessels", None, "no vessel.yaml found")
        self.vessels = {p.parent.name: load_vessel_spec(p) for p in paths}
        self.renderer = BlenderRenderer(PRESETS[config.preset], threads)

    def render_files(self, index: int) -> FrameResult:
        """Render frame ``index`` and return its files (relative path -> bytes)."""
        from harborsight.sim.raycast import check_labels, ray_cast_ids, scene_triangles

        start = time.perf_counter()
        stem = stem_of(index)
        scene = plan_frame(self.config, index, self.vessels)
        rendered = self.renderer.render(scene, cull=self.config.cull_out_of_view)
        geometry = scene.geometry()
        triangles, ids = scene_triangles(scene, rendered.ocean_triangles)
        cast = ray_cast_ids(geometry, triangles, ids)
        agreement = check_labels(rendered.instances, cast, f"frame {stem}")
        image = rendered.image_bgr
        if self.config.wakes:
            image = paint_wakes(image, rendered.instances, scene,
                                np.random.default_rng([self.config.seed, index, WAKE_STREAM]))
        rng = np.random.default_rng([self.config.seed, index, 1])
        target_lightness = None
        if self.config.auto_exposure and scene.scenario in FAMILIES:
            target_lightness = draw_target_lightness(
                np.random.default_rng([self.config.seed, index, METERING_STREAM]))
        image, gain_ev = apply_camera_effects(image, cast.range_m, scene, rng, target_lightness)
        labels = class_mask(rendered.instances, scene.class_of_instance)
        instances = rendered.instances.copy()
        instances[instances == 65535] = 0  # design.md: 0 = water/no object; sky is labels 255
        meta = scene.metadata(f"{stem}.png").to_dict()
        meta["vessel_spec"] = f"vessels/{scene.vessel_dir_name}/vessel.yaml"
        meta["ground_truth"] = scene.ground_truth()
        meta["simulation"] = {
            "generator": f"harborsight.sim {__version__}", "seed": self.config.seed,
            "index": index, "preset": self.config.preset, "camera": self.config.camera,
            "label_agreement": round(agreement, 6), "environment": asdict(scene.environment),
            "split": split_of(self.config, index),
        }
        if target_lightness is not None:
            meta["simulation"]["metered_lightness"] = round(target_lightness, 3)
            meta["simulation"]["metered_gain_ev"] = round(gain_ev, 3)
        meta = with_pose_noise(meta, self.config, stem)
        files = {
            f"images/{stem}.png": _encode_png(image),
            f"labels/{stem}.png": _encode_png(labels),
            f"instances/{stem}.png": _encode_png(instances),
            f"frames/{stem}.json": (json.dumps(meta, indent=1) + "\n").encode(),
        }
        return FrameResult(index, time.perf_counter() - start, agreement, scene.scenario,
                           files=files)

    def render_to_disk(self, index: int) -> FrameResult:
        try:
            result = self.render_files(index)
        except HarborsightError as exc:
            return FrameResult(index, 0.0, error=str(exc))
        except Exception as exc:  # Blender, OpenCV, disk: one frame fails, the batch goes on
            return FrameResult(index, 0.0, error=f"frame {index}: {type(exc).__name__}: {exc}")
        write_frame_files(self.out_dir, result.files)
        result.files = {}
        return result


def with_pose_noise(meta: dict, config: SimulationConfig, stem: str) -> dict:
    """The frame metadata with the configured sensor noise (sim.pose_noise; the same
    errors per (seed, frame) as ``dataset add-pose-noise --seed`` with the dataset's seed),
    or unchanged when the config has none."""
    if not config.pose_noise:
        return meta
    from harborsight.sim.pose_noise import PoseNoise, add_pose_noise, frame_rng

    return add_pose_noise(meta, PoseNoise(**config.pose_noise), frame_rng(config.seed, stem))


def write_frame_files(out_dir: Path, files: dict[str, bytes]) -> None:
    """Write a frame's files; the frame JSON goes last so it marks a finished frame."""
    for rel in sorted(files, key=lambda r: r.startswith("frames/")):
        path = out_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, files[rel])


# ---------------------------------------------------------------------------- workers

_worker: FrameRenderer | None = None
_worker_error: str | None = None


def _init_worker(out_dir: str, config_doc: dict, threads: int) -> None:
    # an initializer that raises makes multiprocessing.Pool restart the worker forever:
    # keep the error and report it for every frame instead
    global _worker, _worker_error
    # a parent that imported bpy passes on sys.path entries of Blender's own scripts, whose
    # pure-Python `bpy` would shadow the compiled module here: drop them before importing
    sys.path[:] = [p for p in sys.path
                   if not (f"{os.sep}bpy{os.sep}" in p and f"{os.sep}scripts" in p)]
    try:
        _worker = FrameRenderer(Path(out_dir), SimulationConfig.from_dict(config_doc), threads)
    except Exception as exc:
        _worker_error = f"render worker failed to start: {type(exc).__name__}: {exc}"


def _worker_render(index: int) -> FrameResult:
    if _worker is None:
        return FrameResult(index, 0.0, error=_worker_error or "render worker not started")
    return _worker.render_to_disk(index)


def render_chunk_files(config_doc: dict, indices: list[int], vessel_files: dict[str, bytes]
                       ) -> list[FrameResult]:
    """A Dask task: render frames in a fresh child process (Blender wants its main thread)
    inside a scratch dataset, and return their files as bytes."""
    with tempfile.TemporaryDirectory(prefix="harborsight-sim-") as tmp:
        root = Path(tmp)
        write_frame_files(root, vessel_files)
        cmd = [sys.executable, "-m", "harborsight.sim.dataset", str(root),
               json.dumps(config_doc), ",".join(str(i) for i in indices)]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            tail = proc.stderr.strip().splitlines()[-5:]
            return [FrameResult(i, 0.0, error="render process failed: " + " | ".join(tail))
                    for i in indices]
        summaries = json.loads((root / "chunk.json").read_text())
        results = []
        for doc in summaries:
            result = FrameResult(**doc)
            if result.error is None:
                stem = stem_of(result.index)
                result.files = {f"{sub}/{stem}.{'json' if sub == 'frames' else 'png'}":
                                (root / sub / f"{stem}.{'json' if sub == 'frames' else 'png'}").read_bytes()
                                for sub in SUBDIRS}
            results.append(result)
        return results


def _chunk_main(argv: list[str]) -> None:
    """Child process of :func:`render_chunk_files`: ``ROOT CONFIG_JSON 1,2,3``."""
    root, config_doc, indices = Path(argv[0]), json.loads(argv[1]), argv[2]
    renderer = FrameRenderer(root, SimulationConfig.from_dict(config_doc))
    summaries = []
    for index in (int(i) for i in indices.split(",")):
        r = renderer.render_to_disk(index)
        summaries.append({"index": r.index, "seconds": r.seconds,
                          "label_agreement": r.label_agreement, "scenario": r.scenario,
                          "error": r.error})
    (root / "chunk.json").write_text(json.dumps(summaries))


# ---------------------------------------------------------------------------- the run


@dataclass
class SimulationSummary:
    rendered: list[FrameResult]
    skipped: int
    failed: list[FrameResult]
    seconds: float


def _check_or_write_dataset_json(out_dir: Path, config: SimulationConfig) -> None:
    path = out_dir / "dataset.json"
    if path.is_file():
        try:
            doc = json.loads(path.read_text())
        except ValueError as exc:
            raise InputError(path, None, f"not valid JSON ({exc}): repair or remove it, or use "
                             "another --out") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("parameters", {}), dict):
            raise InputError(path, "parameters", "expected an object of simulation parameters: "
                             "is this a harborsight dataset?")
        defaults = SimulationConfig(seed=config.seed).to_dict()  # keys added since
        old = {**defaults, **SimulationConfig.LEGACY_PARAMETERS, **doc.get("parameters", {})}
        new = config.to_dict()
        diff = sorted(k for k in new if old.get(k) != new[k])
        if diff:
            raise InputError(path, "parameters", "the dataset was made with other parameters ("
                             + ", ".join(f"{k}: {old.get(k)!r} vs {new[k]!r}" for k in diff)
                             + "); use another --out or the same parameters")


def _blender_version() -> str:
    try:
        from importlib.metadata import version

        return version("bpy")
    except Exception:  # metadata missing: report what we know
        return "unknown"


def _dataset_doc(out_dir: Path, config: SimulationConfig) -> dict:
    stems = sorted(p.stem for p in (out_dir / "frames").glob("*.json"))
    return {
        "generator": f"harborsight.sim {__version__} (Blender {_blender_version()}, Cycles CPU)",
        "seed": config.seed,
        "parameters": config.to_dict(),
        "camera": config.intrinsics().to_dict(),
        "camera_source": CAMERA_PRESETS[config.camera].source,
        "classes": CLASSES,
        "vessels": sorted(p.parent.name for p in (out_dir / "vessels").glob("*/vessel.yaml")),
        "split": {stem: split_of(config, int(stem)) for stem in stems},
    }


def _save_dataset_json(out_dir: Path, config: SimulationConfig) -> None:
    write_bytes_atomic(out_dir / "dataset.json",
                        (json.dumps(_dataset_doc(out_dir, config), indent=1) + "\n").encode())


def simulate(
    out_dir: Path, n_frames: int, config: SimulationConfig, *, workers: int = 1,
    scheduler: str | None = None, chunk_size: int = 4,
    on_frame: Callable[[FrameResult], None] | None = None,
) -> SimulationSummary:
    """Render frames ``0 .. n_frames-1`` of the dataset into ``out_dir`` (resuming)."""
    config.validate()
    start = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    _check_or_write_dataset_json(out_dir, config)
    prepare_vessels(out_dir, config)
    _save_dataset_json(out_dir, config)
    pending = [i for i in range(n_frames)
               if not (out_dir / "frames" / f"{stem_of(i)}.json").is_file()]
    skipped = n_frames - len(pending)
    rendered: list[FrameResult] = []
    failed: list[FrameResult] = []

    def record(result: FrameResult) -> None:
        (failed if result.error else rendered).append(result)
        if not result.error:
            _save_dataset_json(out_dir, config)  # a dataset in the making is usable already
        if on_frame:
            on_frame(result)

    try:
        if not pending:
            pass
        elif scheduler:
            for result in _run_dask(out_dir, config, pending, scheduler, chunk_size):
                record(result)
        elif workers <= 1:
            renderer = FrameRenderer(out_dir, config)
            for index in pending:
                record(renderer.render_to_disk(index))
        else:
            import multiprocessing as mp

            threads = max(1, (os.cpu_count() or 1) // workers)
            ctx = mp.get_context("spawn")
            with ctx.Pool(workers, initializer=_init_worker,
                          initargs=(str(out_dir), config.to_dict(), threads)) as pool:
                for result in pool.imap_unordered(_worker_render, pending):
                    record(result)
    finally:
        _save_dataset_json(out_dir, config)
    return SimulationSummary(rendered, skipped, failed, time.perf_counter() - start)


def _run_dask(out_dir: Path, config: SimulationConfig, pending: list[int], scheduler: str,
              chunk_size: int) -> Iterator[FrameResult]:
    from distributed import Client, as_completed

    vessel_files = {str(p.relative_to(out_dir)): p.read_bytes()
                    for p in (out_dir / "vessels").rglob("*") if p.is_file()}
    chunks = [pending[i:i + chunk_size] for i in range(0, len(pending), chunk_size)]
    with Client(scheduler) as client:
        # one future for the whole dict, keyed by a hash of its content: scattering the dict
        # itself would key each file by its path, the same in every dataset, so two datasets
        # rendering on one cluster would overwrite each other's hulls
        [shared] = client.scatter([vessel_files], broadcast=True, hash=True)
        futures = [client.submit(render_chunk_files, config.to_dict(), chunk, shared,
                                 pure=False) for chunk in chunks]
        for future in as_completed(futures):
            for result in future.result():
                if result.error is None:
                    write_frame_files(out_dir, result.files)
                    result.files = {}
                yield result


if __name__ == "__main__":
    _chunk_main(sys.argv[1:])
