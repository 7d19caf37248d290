"""Fuzz every parser and ``measure_frame`` with many generated cases (issue #30's target:
10,000 cases per parser, no crash outside the project's error type).

The cases are those of the property tests (``tests/fuzz_cases.py``), drawn by Hypothesis
without shrinking. For each target it prints the cases run, how many the parser accepted
(``ok``) or refused with a one-line :class:`HarborsightError` (``refused``), and the
crashes: any other exception, a failed check of an accepted result (``AssertionError``),
or a case that ran past ``--case-timeout-s``. The first crash of each kind is shown.

    .venv/bin/python benchmarks/fuzz_parsers.py [--cases 10000] [--only nmea,dji-srt]
        [--seed 0] [--json results.json]

Exit code 1 when any target crashed.
"""

from __future__ import annotations

import argparse
import collections
import json
import signal
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tests.fuzz_cases

from hypothesis import HealthCheck, Phase, given, seed, settings

from tests.fuzz_cases import TARGETS, log_seed


class CaseTimeoutError(Exception):
    """A case ran past its time limit."""


def _alarm(signum, frame):
    raise CaseTimeoutError


#: cases per Hypothesis run: a run holds on to what it drew until it ends (0.6 MB a case for
#: the PX4 log, 6 GB at 10,000), so a target's cases are drawn in runs of this many
CHUNK = 500


def fuzz(name: str, cases: int, random_seed: int, timeout_s: float) -> dict:
    """Run ``cases`` cases of one target (in runs of :data:`CHUNK`, each with its own seed);
    counts and the first crash of each kind."""
    counts: collections.Counter = collections.Counter()
    crashes: dict[str, str] = {}
    started = time.perf_counter()
    for chunk, first in enumerate(range(0, cases, CHUNK)):
        _fuzz_chunk(name, min(CHUNK, cases - first), random_seed * 1_000_003 + chunk, timeout_s,
                    counts, crashes)
    seconds = time.perf_counter() - started
    return {"target": name, "cases": sum(counts.values()), "ok": counts["ok"],
            "refused": counts["refused"], "crashes": counts["crash"],
            "seconds": round(seconds, 1), "first_crash_of_each_kind": crashes}


def _fuzz_chunk(name: str, cases: int, random_seed: int, timeout_s: float,
                counts: collections.Counter, crashes: dict[str, str]) -> None:
    """One Hypothesis run of ``cases`` cases, added to ``counts`` and ``crashes``."""
    strategy, run = TARGETS[name]

    @seed(random_seed)
    @settings(max_examples=cases, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def body(case) -> None:
        signal.setitimer(signal.ITIMER_REAL, timeout_s)
        try:
            counts[run(case)] += 1
        except CaseTimeoutError:
            counts["crash"] += 1
            crashes.setdefault("timeout", f"ran past {timeout_s} s: {_brief(case)}")
        except Exception as exc:   # every crash is counted, none stops the run
            counts["crash"] += 1
            kind = f"{type(exc).__name__}"
            where = traceback.extract_tb(exc.__traceback__)[-1]
            crashes.setdefault(kind, f"{str(exc)[:200]!r} at {Path(where.filename).name}:"
                                     f"{where.lineno}; case {_brief(case)}")
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)

    body()


def _brief(case, limit: int = 700) -> str:
    text = repr(case)
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} characters)"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=10_000, help="cases per target")
    parser.add_argument("--only", help="comma list of targets (default: all): " + ", ".join(TARGETS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--case-timeout-s", type=float, default=20.0)
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    names = args.only.split(",") if args.only else list(TARGETS)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        parser.error(f"unknown target(s) {unknown}; known: {', '.join(TARGETS)}")
    signal.signal(signal.SIGALRM, _alarm)
    results = []
    print(f"{'target':<15} {'cases':>7} {'ok':>7} {'refused':>8} {'crashes':>8} {'seconds':>8}")
    for name in names:
        if name in ("px4-ulog", "ardupilot-bin") and not log_seed(
                "px4/sample_log_small.ulg" if name == "px4-ulog" else "ardupilot/test.BIN"):
            print(f"{name:<15} skipped: no sample log in ../shared/data/telemetry")
            continue
        result = fuzz(name, args.cases, args.seed, args.case_timeout_s)
        results.append(result)
        print(f"{name:<15} {result['cases']:>7} {result['ok']:>7} {result['refused']:>8} "
              f"{result['crashes']:>8} {result['seconds']:>8}", flush=True)
        for kind, example in result["first_crash_of_each_kind"].items():
            print(f"    {kind}: {example}", flush=True)
    total = sum(r["crashes"] for r in results)
    print(f"crashes outside HarborsightError: {total} in {sum(r['cases'] for r in results)} cases")
    if args.json:
        args.json.write_text(json.dumps({"cases_per_target": args.cases, "seed": args.seed,
                                         "results": results}, indent=2) + "\n")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
