"""How long a ``granseg`` command takes from start to exit, for one or more trees taking turns.

    PYTHONPATH=python python benches/bench_cli_start.py [--trees . /tmp/base] [--turns 4]

Each turn starts a fresh interpreter per tree and command, with ``PYTHONPATH`` at the tree's
``python/`` folder, and times it to its exit (the command's whole wall time, as a user waits
for it). Trees take turns so that a machine that slows down for a minute slows each alike; the
table gives each tree's least and most over the turns.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMANDS = {
    "granseg --help": ["--help"],
    "granseg simulate --help": ["simulate", "--help"],
    "granseg diagnose --help": ["diagnose", "--help"],
    "granseg simulate (defaults)": ["simulate", "--out", "{tmp}/map", "--force"],
}


def seconds(tree: Path, argv: list[str]) -> float:
    """Wall time [s] of ``granseg argv`` run from ``tree``'s sources; a failure stops the bench."""
    env = {**os.environ, "PYTHONPATH": str(tree / "python")}
    code = "import sys; from granseg.cli import main; sys.exit(main(sys.argv[1:]))"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code, *argv], env=env, check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trees", nargs="+", type=Path, default=[Path(".")], help="source trees to compare")
    ap.add_argument("--turns", type=int, default=4)
    args = ap.parse_args()
    times: dict[tuple[str, Path], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for turn in range(args.turns):
            for name, argv in COMMANDS.items():
                for tree in args.trees:
                    t = seconds(tree, [a.format(tmp=tmp) for a in argv])
                    times.setdefault((name, tree), []).append(t)
            print(f"turn {turn + 1} of {args.turns} done", file=sys.stderr, flush=True)
    print("| command | " + " | ".join(str(t) for t in args.trees) + " |")
    print("|---|" + "---|" * len(args.trees))
    for name in COMMANDS:
        cells = [f"{min(times[name, t]):.2f}-{max(times[name, t]):.2f} s" for t in args.trees]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
