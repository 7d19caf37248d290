"""The bundled demo samples: a harbour tug in five Blender-rendered harbour scenes, and a
24 s flight of the tug berthing at a quay.

``harborsight make-samples`` regenerates them from their seeds; the committed copy lives in
``harborsight/data/samples`` (dataset layout of ``docs/design.md``) with the flight in its
``flight/`` folder (JPEG images to keep the repository small; labels and metadata exact).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import cv2
import yaml

from harborsight.errors import InputError
from harborsight.sim.dataset import SimulationConfig, simulate
from harborsight.telemetry.writers import write_flight_logs
from harborsight.vessel.hullgen import HullParameters, generate_hull_mesh

DEFAULT_SEED = 20260501

#: the demo's frames: scenario and drone height above water (m), frame i of the dataset
DEMO_SCENARIOS = ("alongside", "slip", "touching", "pass", "open")
DEMO_ALTITUDES_M = (40.0, 60.0, 50.0, 80.0, 110.0)


def write_example_vessel(vessels_dir: Path) -> Path:
    """The demo's vessel: a 32 m harbour tug (procedural hull mesh, STL)."""
    tug = vessels_dir / "harbour-tug"
    tug.mkdir(parents=True, exist_ok=True)
    generate_hull_mesh(HullParameters()).export(tug / "hull.stl")
    (tug / "vessel.yaml").write_text(
        "# A 32 m harbour tug. hull.stl is procedural (harborsight.vessel.hullgen), in metres,\n"
        "# naval CAD axes; origin on the centreline at the transom, z = 0 at the waterline.\n"
        + yaml.safe_dump({
            "name": "harbour-tug",
            "hull_mesh": "hull.stl",
            "mesh_axes": ["bow", "port", "up"],
            "gps_antenna": [20.0, 0.0, 9.0],
            "waterline_m": 0.0,
            "outline": "waterline",
            "sections": 16,
        }, sort_keys=False)
    )
    return tug / "vessel.yaml"


def demo_config(seed: int = DEFAULT_SEED) -> SimulationConfig:
    return SimulationConfig(
        seed=seed, preset="default", altitudes_m=DEMO_ALTITUDES_M,
        vessel_spec="vessels/harbour-tug/vessel.yaml", scenario=",".join(DEMO_SCENARIOS),
        split="demo")


def check_replaceable(out_dir: Path) -> None:
    """``out_dir`` may be (re)written by ``make-samples``: absent, empty, or an earlier demo
    samples folder (its ``dataset.json`` parameters say split ``demo``). Anything else is
    refused, so that ``--out .`` or ``--out data/train`` never deletes a user's files."""
    if not out_dir.exists() or (out_dir.is_dir() and not any(out_dir.iterdir())):
        return
    try:
        split = json.loads((out_dir / "dataset.json").read_text())["parameters"]["split"]
    except (OSError, ValueError, KeyError, TypeError):
        split = None
    if not out_dir.is_dir() or split != "demo":
        raise InputError(out_dir, None, "exists and is not a demo samples folder (no "
                         "dataset.json with split 'demo'): refusing to replace it; give a new "
                         "or empty folder")


def _replace_folder(out_dir: Path, built: Path) -> None:
    """Put the finished ``built`` folder where ``out_dir`` was (old one removed only now)."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    built.rename(out_dir)


def make_demo_samples(out_dir: Path, seed: int = DEFAULT_SEED, n_frames: int | None = None
                      ) -> list[str]:
    """Render the demo dataset into ``out_dir`` with the Blender simulator; returns the
    frame stems. It is rendered beside ``out_dir`` and replaces it only when every frame was
    rendered (:func:`check_replaceable` first). ``n_frames`` renders only the first frames
    (tests)."""
    check_replaceable(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir.parent, prefix=f".{out_dir.name}-") as tmp:
        work = Path(tmp) / "samples"
        write_example_vessel(work / "vessels")
        summary = simulate(work, n_frames or len(DEMO_SCENARIOS), demo_config(seed))
        if summary.failed:
            raise RuntimeError("; ".join(f.error or "" for f in summary.failed))
        _replace_folder(out_dir, work)
    return sorted(p.stem for p in (out_dir / "frames").glob("*.json"))


#: the flight: scene seed (an alongside berth 8.7 m off the quay), frames, interval, speed
FLIGHT_SEED = 8
FLIGHT_FRAMES = 48
FLIGHT_INTERVAL_S = 0.5
FLIGHT_SPEED_MPS = 0.4
FLIGHT_ALTITUDE_M = 60.0
FLIGHT_JPEG_QUALITY = 90


def flight_config(seed: int = FLIGHT_SEED) -> SimulationConfig:
    return SimulationConfig(
        seed=seed, preset="default", altitudes_m=(FLIGHT_ALTITUDE_M,),
        vessel_spec="vessels/harbour-tug/vessel.yaml", scenario="alongside", split="demo",
        sequence_frames=FLIGHT_FRAMES, frame_interval_s=FLIGHT_INTERVAL_S,
        approach_speed_mps=FLIGHT_SPEED_MPS)


def make_demo_flight(samples_dir: Path, seed: int = FLIGHT_SEED, n_frames: int | None = None
                     ) -> Path:
    """Render the demo flight into ``samples_dir/flight`` (replacing it once every frame is
    rendered): frames/*.json, images/*.jpg, labels/*.png, and logs/ (flight.SRT, ship.nmea,
    flight.mp4: the flight as real-format inputs of ``telemetry video``); the frames name the
    tug in ``samples_dir/vessels``."""
    final = samples_dir / "flight"
    samples_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=samples_dir, prefix=".flight-") as tmp:
        work = Path(tmp) / "render"
        flight = Path(tmp) / "flight"
        write_example_vessel(work / "vessels")
        summary = simulate(work, n_frames or FLIGHT_FRAMES, flight_config(seed))
        if summary.failed:
            raise RuntimeError("; ".join(f.error or "" for f in summary.failed))
        for sub in ("frames", "images", "labels"):
            (flight / sub).mkdir(parents=True)
        for meta_path in sorted((work / "frames").glob("*.json")):
            stem = meta_path.stem
            meta = json.loads(meta_path.read_text())
            meta["image"] = f"{stem}.jpg"
            meta["vessel_spec"] = "../vessels/harbour-tug/vessel.yaml"
            (flight / "frames" / meta_path.name).write_text(json.dumps(meta, indent=1) + "\n")
            image = cv2.imread(str(work / "images" / f"{stem}.png"))
            cv2.imwrite(str(flight / "images" / f"{stem}.jpg"), image,
                        [cv2.IMWRITE_JPEG_QUALITY, FLIGHT_JPEG_QUALITY])
            shutil.copy(work / "labels" / f"{stem}.png", flight / "labels" / f"{stem}.png")
        shutil.copy(work / "dataset.json", flight / "dataset.json")
        # the same flight as a drone's SRT, a vessel's NMEA feed and a video (README example)
        write_flight_logs(flight, flight / "logs")
        _replace_folder(final, flight)
    return final
