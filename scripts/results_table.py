"""Print docs/results.md's per-altitude table from `evaluate distance` summaries.

Usage: python scripts/results_table.py FLAT_ORACLE/summary.json [MODEL/summary.json]

The first summary must hold the flat and oracle rows (``--flat-world``, both methods); the
second, if given, the model's ground_plane rows (``--no-oracle --model M``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HEADER = ("| altitude m | n | flat gp median px | oracle gp median px | oracle gsd median px "
          "| flat gp MAE | oracle gp MAE ± std | oracle gsd MAE ± std | oracle gp > 1 m "
          "| oracle gsd > 1 m | model gp MAE ± std | model gp median px | model missed / false |")


def _row(rows: list[dict], masks: str, method: str, altitude_m: int) -> dict | None:
    for row in rows:
        if row["masks"].startswith(masks) and row["method"] == method \
                and row["altitude_m"] == altitude_m:
            return row
    return None


def table(flat_oracle: list[dict], model: list[dict]) -> str:
    lines = [HEADER, "|" + "---:|" * (HEADER.count("|") - 1)]
    for altitude_m in sorted({row["altitude_m"] for row in flat_oracle}):
        flat = _row(flat_oracle, "flat", "ground_plane", altitude_m)
        oracle = _row(flat_oracle, "oracle", "ground_plane", altitude_m)
        oracle_gsd = _row(flat_oracle, "oracle", "gsd", altitude_m)
        learned = _row(model, "model", "ground_plane", altitude_m)
        model_cells = (f"{learned['mae_m']:.2f} ± {learned['std_m']:.2f} | "
                       f"{learned['median_px']:.2f} | {learned['missed']} / {learned['false']}"
                       if learned else "– | – | –")
        lines.append(
            f"| {altitude_m} | {oracle['n']} | {flat['median_px']:.2f} | {oracle['median_px']:.2f} "
            f"| {oracle_gsd['median_px']:.2f} | {flat['mae_m']:.2f} "
            f"| {oracle['mae_m']:.2f} ± {oracle['std_m']:.2f} "
            f"| {oracle_gsd['mae_m']:.2f} ± {oracle_gsd['std_m']:.2f} "
            f"| {100 * oracle['over_1m_share']:.1f} % | {100 * oracle_gsd['over_1m_share']:.1f} % "
            f"| {model_cells} |")
    return "\n".join(lines)


def main(argv: list[str]) -> None:
    if len(argv) not in (2, 3):
        raise SystemExit(__doc__)
    flat_oracle = json.loads(Path(argv[1]).read_text())
    model = json.loads(Path(argv[2]).read_text()) if len(argv) == 3 else []
    print(table(flat_oracle, model))


if __name__ == "__main__":
    main(sys.argv)
