"""docs/sim-vs-real.jpg: lake-shore and marina renders beside real lake-shore photos and marina
tiles (issue #26, item 4), alternating. ../shared beside the checkout.

    .venv/bin/python scripts/sim_vs_real_sheet.py DATASET [--out docs/sim-vs-real.jpg] [--pairs 3]
    .venv/bin/python scripts/sim_vs_real_sheet.py DATASET --lake-shore 000007,000010 --out F.jpg

``--lake-shore STEMS`` puts those renders beside lake-shore photos instead of the first of
each family.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2

from harborsight.viz.contact_sheet import renders_beside_real

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
LAKE = ["DJI_0262.jpg", "DJI_0290.jpg", "DJI_0310.jpg", "DJI_0283.jpg"]
MARINA = ["harbor05.tif", "harbor33.tif", "harbor12.tif", "harbor47.tif"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/sim-vs-real.jpg"))
    parser.add_argument("--pairs", type=int, default=3, help="rows of each family")
    parser.add_argument("--lake-shore", default="", help="comma-separated render stems, each "
                        "beside a lake-shore photo (no marina rows)")
    args = parser.parse_args()
    if args.lake_shore:
        stems = args.lake_shore.split(",")
        real = [REAL / "aerial-maritime-drone" / "photos" / LAKE[k % len(LAKE)] for k in range(len(stems))]
        write(renders_beside_real(args.dataset, stems, real, tile_width=480), args.out, len(stems))
        return
    by_family: dict[str, list[str]] = {"lakeshore": [], "marina": []}
    for path in sorted((args.dataset / "frames").glob("*.json")):
        family = json.loads(path.read_text()).get("ground_truth", {}).get("scenario")
        if family in by_family and len(by_family[family]) < args.pairs:
            by_family[family].append(path.stem)
    stems, real = [], []
    for k in range(args.pairs):
        for family, names, folder in (("lakeshore", LAKE, REAL / "aerial-maritime-drone" / "photos"),
                                      ("marina", MARINA, REAL / "ucmerced-harbor")):
            if k < len(by_family[family]):
                stems.append(by_family[family][k])
                real.append(folder / names[k % len(names)])
    write(renders_beside_real(args.dataset, stems, real, tile_width=480), args.out, len(stems))


def write(sheet, out: Path, pairs: int) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), sheet, [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"{out}: {pairs} pairs")


if __name__ == "__main__":
    main()
