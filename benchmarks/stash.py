"""Carries a long benchmark run from one machine to the next, as one file kept in the repository.

The paper's protocol takes ~14 h on a 2-core CPU: several sittings, and the folder a run lives
in does not outlive the machine. ``save`` packs the run directory (safely, while it runs) into an
xz-compressed tar; commit that file. On a new machine, ``restore`` unpacks it, and the same
``compare.py`` command with the same ``--out`` resumes the run from the packed checkpoint, which
``restore`` signs with the new machine's key (hritest loads only checkpoints signed by their user,
see :mod:`hritest.rundir`), so restore only files you packed yourself::

    python benchmarks/stash.py save /work/runs/teleop-paper/sas-s0 benchmarks/results/teleop-paper-sas-s0.tar.xz
    python benchmarks/stash.py restore benchmarks/results/teleop-paper-sas-s0.tar.xz /work/runs/teleop-paper
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hritest.errors import HritestError
from hritest.rundir import RunDirectory, atomic_write, unpack


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    save = verbs.add_parser("save", help="pack a run directory into FILE (replaced atomically)")
    save.add_argument("run", type=Path)
    save.add_argument("file", type=Path)
    restore = verbs.add_parser("restore", help="unpack FILE's run as a new folder under INTO")
    restore.add_argument("file", type=Path)
    restore.add_argument("into", type=Path)
    args = parser.parse_args()
    try:
        if args.verb == "save":
            data = RunDirectory.open(args.run).pack()
            args.file.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(args.file, data)
            print(f"{args.run} -> {args.file} ({len(data) / 2**20:.1f} MiB)")
        else:
            run = unpack(args.file, args.into)
            run.adopt()  # your own run, packed on another machine: signed with this machine's key
            print(f"{args.file} -> {run.path}; resume it with the compare.py command that started it")
    except HritestError as exc:
        sys.exit(f"error: {exc}")


if __name__ == "__main__":
    main()
