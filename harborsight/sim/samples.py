"""The bundled demo samples: two example vessels in schematic harbour scenes.

``harborsight make-samples`` regenerates them from a seed; the committed copy lives in
``harborsight/data/samples`` (dataset layout of ``docs/design.md``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import yaml

from harborsight import __version__
from harborsight.sim.schematic import DEFAULT_INTRINSICS, sample_scene, write_frame
from harborsight.vessel.hullgen import HullParameters, generate_hull_mesh
from harborsight.vessel.spec import load_vessel_spec

DEFAULT_SEED = 20260501

#: (stem, vessel, scenario, altitude m, tilt deg, gap m)
DEMO_FRAMES = [
    ("000000", "harbour-tug", "alongside", 60.0, 0.0, 4.0),
    ("000001", "coastal-ferry", "slip", 90.0, 12.0, 6.0),
    ("000002", "harbour-tug", "touching", 45.0, 5.0, None),
    ("000003", "coastal-ferry", "open", 120.0, 0.0, None),
    ("000004", "harbour-tug", "slip", 30.0, 15.0, 2.5),
]


def write_example_vessels(vessels_dir: Path) -> dict[str, Path]:
    """A mesh-based tug (procedural hull, STL) and an AIS-dimensions ferry."""
    tug = vessels_dir / "harbour-tug"
    tug.mkdir(parents=True, exist_ok=True)
    params = HullParameters()
    generate_hull_mesh(params).export(tug / "hull.stl")
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
    ferry = vessels_dir / "coastal-ferry"
    ferry.mkdir(parents=True, exist_ok=True)
    (ferry / "vessel.yaml").write_text(
        "# A 60 m coastal ferry described as its AIS static data would (distances from the\n"
        "# GPS antenna, metres); air_draft_m bounds its superstructure for the own-vessel mask.\n"
        + yaml.safe_dump({
            "name": "coastal-ferry",
            "dimensions": {"to_bow": 42.0, "to_stern": 18.0, "to_port": 7.0, "to_starboard": 7.0},
            "air_draft_m": 12.0,
            "outline": "waterline",
            "section_length_m": 10.0,
        }, sort_keys=False)
    )
    return {"harbour-tug": tug / "vessel.yaml", "coastal-ferry": ferry / "vessel.yaml"}


def make_demo_samples(out_dir: Path, seed: int = DEFAULT_SEED) -> list[str]:
    """Write the demo dataset to ``out_dir`` (replacing it); returns the frame stems."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    specs = {name: load_vessel_spec(path)
             for name, path in write_example_vessels(out_dir / "vessels").items()}
    rng = np.random.default_rng(seed)
    split = {}
    for i, (stem, vessel_name, scenario, altitude, tilt, gap) in enumerate(DEMO_FRAMES):
        scene = sample_scene(
            specs[vessel_name], rng, altitude_m=altitude, tilt_deg=tilt, scenario=scenario,
            gap_m=gap, name=stem, timestamp=f"2026-05-01T12:00:{i * 2:02d}.000Z",
        )
        write_frame(scene, out_dir, stem, vessel_dir_name=vessel_name)
        split[stem] = "demo"
    (out_dir / "dataset.json").write_text(json.dumps({
        "generator": f"harborsight.sim.schematic {__version__}",
        "seed": seed,
        "parameters": {"frames": [list(f) for f in DEMO_FRAMES],
                       "camera": DEFAULT_INTRINSICS.to_dict()},
        "classes": {"0": "water", "1": "ship", "2": "obstacle", "255": "ignore"},
        "split": split,
    }, indent=2) + "\n")
    return list(split)
