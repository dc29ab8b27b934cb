"""The search process's memory as a run grows: resident set size against evaluations.

    python benchmarks/memory.py specs/teleop.yaml --budget 100000 [--algorithm cma_mae] \\
        [--workers 2] [--every 10] [--out DIR]

A long model-free run must not keep every evaluation in memory. This runs ``hritest search`` as
a child process and samples the resident memory of the search process itself (not its workers,
whose memory is the simulator's and does not grow with the run) every ``--every`` seconds,
beside the evaluations written so far. Prints a Markdown table of the samples at each tenth of
the budget, the peak, and the growth per 100,000 evaluations between the first tenth and the end.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import psutil


def written(run: Path) -> int:
    """Evaluations in the run directory (committed lines)."""
    try:
        with open(run / "evaluations.jsonl", "rb") as handle:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: handle.read(1 << 20), b""))
    except OSError:
        return 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("spec", type=Path)
    parser.add_argument("--budget", type=int, default=100_000)
    parser.add_argument("--algorithm", default="cma_mae")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--every", type=float, default=10.0, help="seconds between samples")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path("benchmark-runs") / f"memory-{args.spec.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    command = [
        sys.executable,
        "-m",
        "hritest.cli",
        "search",
        str(args.spec),
        "--algorithm",
        args.algorithm,
        "--budget",
        str(args.budget),
        "--workers",
        str(args.workers),
        "--quiet",
        "--out",
        str(out),
    ]
    started = time.monotonic()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    process = psutil.Process(child.pid)
    samples: list[tuple[float, int, float]] = []  # (seconds, evaluations, resident MB)
    while child.poll() is None:
        try:
            rss = process.memory_info().rss / 2**20
        except psutil.NoSuchProcess:
            break
        samples.append((time.monotonic() - started, written(out), rss))
        time.sleep(args.every)
    child.wait()

    during = [s for s in samples if s[1] < args.budget]  # not the report written after the search
    marks = [args.budget * k // 10 for k in range(1, 11)]
    lines = [
        f"{args.spec.name}, {args.algorithm}, {args.budget:,} evaluations, {args.workers} workers: "
        "the search process's resident memory",
        "",
        "| evaluations | seconds | resident MB |",
        "|---|---|---|",
    ]
    for mark in marks:
        at = [s for s in during if s[1] <= mark]
        if at:
            seconds, evaluations, rss = at[-1]
            lines.append(f"| {evaluations:,} | {seconds:.0f} | {rss:.0f} |")
    if during:
        first = next((s for s in during if s[1] >= args.budget // 10), during[0])
        last = during[-1]
        growth = (last[2] - first[2]) / max(last[1] - first[1], 1) * 100_000
        lines += [
            "",
            f"peak {max(s[2] for s in during):.0f} MB; {growth:+.1f} MB per 100,000 evaluations between "
            f"{first[1]:,} and {last[1]:,}; exit status {child.returncode}",
        ]
    table = "\n".join(lines)
    print(table)
    (out / "memory.md").write_text(table + "\n")


if __name__ == "__main__":
    main()
