"""``harborsight vessel``: vessel specs (vessel.yaml) from what ships broadcast."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
import yaml

from harborsight.cli.app import app, console, err_console
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_file

vessel_app = typer.Typer(rich_markup_mode=None, no_args_is_help=True,
                         help="Vessel specs (vessel.yaml): hull outline and sections.")
app.add_typer(vessel_app, name="vessel")


@vessel_app.command("from-ais")
def vessel_from_ais(
    ais_log: Annotated[Path, typer.Argument(metavar="AIS_LOG",
                                            help="AIVDM/AIVDO sentences (a receiver's log).")],
    out: Annotated[Path, typer.Option(help="The vessel.yaml to write.")],
    mmsi: Annotated[int | None, typer.Option(
        min=1, max=999_999_999, help="The vessel (default: the file's own AIVDO reports, or "
        "its only vessel).")] = None,
    bow: Annotated[str, typer.Option(
        help="pointed (a ship: a triangle one beam long, at most 35 % of the length) or box "
        "(a barge or pontoon).")] = "pointed",
    sections: Annotated[int, typer.Option(min=1, max=1000, help="Sections around the hull.")] = 16,
) -> None:
    """Write a vessel.yaml from the hull's AIS dimensions (type 5, 19 or 24 B: A to the bow,
    B to the stern, C to port, D to starboard, from the GPS reference point, which is the
    vessel frame's origin). Dimensions at AIS's largest codes (511, 63 m) mean that or more:
    said, and kept as they are. The hull is drawn from whole metres and a guessed bow, so
    the spec says how far it may lie from the real one (outline_sigma_m, 0.6 m, measured on
    the synthetic bench's hulls), which widens every distance's error bar."""
    from harborsight.telemetry.ais import read_ais_dimensions
    from harborsight.vessel.outline import BOW_SHAPES
    from harborsight.vessel.spec import AIS_OUTLINE_SIGMA_M, load_vessel_spec

    try:
        if bow not in BOW_SHAPES:
            raise InputError(None, "--bow", f"{bow!r}: expected one of {', '.join(BOW_SHAPES)}")
        if not ais_log.is_file():
            raise InputError(ais_log, None, "file not found")
        prepare_output_file(out, "--out")
        dims, notes = read_ais_dimensions(ais_log, mmsi)
        name = (dims.name or f"mmsi-{dims.mmsi}").lower().replace(" ", "-")
        doc = {"name": name, "mmsi": dims.mmsi,
               "dimensions": {"to_bow": dims.to_bow, "to_stern": dims.to_stern,
                              "to_port": dims.to_port, "to_starboard": dims.to_starboard, "bow": bow},
               "outline": "waterline", "outline_sigma_m": AIS_OUTLINE_SIGMA_M, "sections": sections}
        header = (f"# From AIS: MMSI {dims.mmsi}" + (f", {dims.name}" if dims.name else "")
                  + f", read from {ais_log.name} by `harborsight vessel from-ais`.\n"
                  "# Dimensions in metres from the GPS reference point (the vessel frame's origin).\n"
                  "# outline_sigma_m: how far (one sigma) a hull drawn from whole-metre dimensions and a\n"
                  "# guessed bow lies from the real one; it widens every distance's error bar. Lower it\n"
                  "# only for a hull measured better (or give a hull_mesh).\n")
        out.write_text(header + yaml.safe_dump(doc, sort_keys=False))
        spec = load_vessel_spec(out)            # what was written reads back as a spec
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    for note in notes:
        err_console.print(f"note: {ais_log}: {note}", markup=False, highlight=False)
    if dims.at_least:
        err_console.print(f"note: {', '.join(dims.at_least)} at AIS's largest code: the hull is "
                          "that long or more there", markup=False, highlight=False)
    console.print(f"{out}: {dims.name or dims.mmsi}, {dims.to_bow + dims.to_stern} x "
                  f"{dims.to_port + dims.to_starboard} m, {bow} bow, {spec.sections().n_sections} sections",
                  highlight=False)
