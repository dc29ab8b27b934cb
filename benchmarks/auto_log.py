"""What an ``--algorithm auto`` run chose, stint by stint, from its ``auto.json``.

    python benchmarks/auto_log.py RUN [RUN ...]

Prints one line per stint (when it began, its arm and why, its seconds and batches, QD-score
gained, its gain over the pace before it, and every measured arm's score when it began), then
each arm's share of the time. What the tables of ``benchmarks/README.md`` say about why auto
chose as it did was read from this.
"""

from __future__ import annotations

import argparse
import json
import sys
from itertools import groupby
from pathlib import Path

from hritest.search.auto import FILE


def stints(batches: list[dict]) -> list[dict]:
    """The batches grouped into stints: start second, arm, reason, seconds, batches, gain, relative."""
    out, clock = [], 0.0
    for _, grouped in groupby(batches, key=lambda b: b["stint"]):
        group = list(grouped)
        seconds = sum(b["seconds"] for b in group)
        gain = sum(b["gain"] for b in group)
        pace = group[0]["pace"]
        out.append(
            {
                "start": clock,
                "arm": group[0]["arm"],
                "reason": group[0]["reason"],
                "seconds": seconds,
                "batches": len(group),
                "gain": gain,
                "relative": gain / (pace * seconds) if pace > 0 and seconds > 0 else float("nan"),
                "rates": group[0]["rates"],
            }
        )
        clock += seconds
    return out


def show(run: Path) -> None:
    log = json.loads((run / FILE).read_text())
    print(f"# {run}")
    print(f"{'start s':>8} {'arm':<11} {'reason':<26} {'s':>6} {'n':>3} {'gain':>9} {'rel':>5}  scores at start")
    for s in stints(log["batches"]):
        rates = " ".join(f"{arm}={score:.2f}" for arm, score in s["rates"].items())
        print(
            f"{s['start']:8.1f} {s['arm']:<11} {s['reason'][:26]:<26} {s['seconds']:6.1f} {s['batches']:3d}"
            f" {s['gain']:9.1f} {s['relative']:5.2f}  {rates}"
        )
    shares = ", ".join(f"{arm} {a['time_share']:.0%}" for arm, a in log["arms"].items())
    print(f"time: {shares}\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args()
    for run in args.runs:
        if not (run / FILE).is_file():
            sys.exit(f"error: {run} has no {FILE}: it is not an --algorithm auto run directory")
        show(run)


if __name__ == "__main__":
    main()
