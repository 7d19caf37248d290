"""The bundled demo samples: a harbour tug in five Blender-rendered harbour scenes.

``harborsight make-samples`` regenerates them from a seed; the committed copy lives in
``harborsight/data/samples`` (dataset layout of ``docs/design.md``).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from harborsight.sim.dataset import SimulationConfig, simulate
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


def make_demo_samples(out_dir: Path, seed: int = DEFAULT_SEED, n_frames: int | None = None
                      ) -> list[str]:
    """Render the demo dataset into ``out_dir`` (replacing it) with the Blender simulator;
    returns the frame stems. ``n_frames`` renders only the first frames (tests)."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    write_example_vessel(out_dir / "vessels")
    summary = simulate(out_dir, n_frames or len(DEMO_SCENARIOS), demo_config(seed))
    if summary.failed:
        raise RuntimeError("; ".join(f.error or "" for f in summary.failed))
    return sorted(p.stem for p in (out_dir / "frames").glob("*.json"))
