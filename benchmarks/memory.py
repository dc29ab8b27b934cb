"""The search process's memory as a run grows: resident set size against evaluations.

    python benchmarks/memory.py specs/teleop.yaml --budget 100000 [--algorithm cma_mae] \\
        [--workers 2] [--every 10] [--out DIR]

A long model-free run must not keep every evaluation in memory. This runs ``hritest search`` as
a child process and samples the resident memory of the search process itself (not its workers,
whose memory is the simulator's and does not grow with the run) every ``--every`` seconds,
beside the evaluations written so far. Prints a Markdown table of the samples at each tenth of
the budget, the peak, and the growth per 100,000 evaluations between the first tenth and the end.

A measurement too long for one sitting continues: the same command with the same ``--out`` resumes
the stopped run (``hritest search --resume``) and adds to its samples, kept in ``memory.csv``
(a resumed process starts by loading the run's state, which is part of what it must keep flat).
"""

from __future__ import annotations

import argparse
import csv
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


def read_samples(log: Path) -> list[tuple[int, float, int, float]]:
    """The samples of earlier sittings of this measurement."""
    try:
        with open(log, newline="") as handle:
            return [(int(a), float(b), int(c), float(d)) for a, b, c, d in csv.reader(handle)]
    except OSError:
        return []


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
    log = out / "memory.csv"
    samples = read_samples(log)  # (sitting, seconds, evaluations, resident MB), earlier sittings' too
    sitting = max((s[0] for s in samples), default=-1) + 1
    common = ["--workers", str(args.workers), "--quiet"]
    if (out / "checkpoint.pkl").is_file():
        command = ["search", "--resume", str(out), *common]
    else:
        command = ["search", str(args.spec), "--algorithm", args.algorithm, "--budget", str(args.budget), *common]
        command += ["--out", str(out)]
    started = time.monotonic()
    child = subprocess.Popen([sys.executable, "-m", "hritest.cli", *command], stdout=subprocess.DEVNULL)
    process = psutil.Process(child.pid)
    while child.poll() is None:
        try:
            rss = process.memory_info().rss / 2**20
        except psutil.NoSuchProcess:
            break
        sample = (sitting, round(time.monotonic() - started, 1), written(out), round(rss, 1))
        if out.is_dir():
            with open(log, "a", newline="") as handle:
                csv.writer(handle).writerow(sample)
        samples.append(sample)
        time.sleep(args.every)
    child.wait()

    during = [s for s in samples if s[2] < args.budget]  # not the report written after the search
    marks = [args.budget * k // 10 for k in range(1, 11)]
    lines = [
        f"{args.spec.name}, {args.algorithm}, {args.budget:,} evaluations, {args.workers} workers: "
        "the search process's resident memory",
        "",
        "| evaluations | sitting | seconds into it | resident MB |",
        "|---|---|---|---|",
    ]
    for mark in marks:
        at = [s for s in during if s[2] <= mark]
        if at:
            part, seconds, evaluations, rss = at[-1]
            lines.append(f"| {evaluations:,} | {part + 1} | {seconds:.0f} | {rss:.0f} |")
    if during:
        first = next((s for s in during if s[2] >= args.budget // 10), during[0])
        last = during[-1]
        growth = (last[3] - first[3]) / max(last[2] - first[2], 1) * 100_000
        lines += [
            "",
            f"peak {max(s[3] for s in during):.0f} MB; {growth:+.1f} MB per 100,000 evaluations between "
            f"{first[2]:,} and {last[2]:,}; {sitting + 1} sitting(s); exit status {child.returncode}",
        ]
    table = "\n".join(lines)
    print(table)
    (out / "memory.md").write_text(table + "\n")


if __name__ == "__main__":
    main()
