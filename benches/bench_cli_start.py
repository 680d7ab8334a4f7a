"""How long a ``granseg`` command takes from start to exit, for one or more trees taking turns.

    PYTHONPATH=python python benches/bench_cli_start.py [--trees . /tmp/base] [--turns 4]
    PYTHONPATH=python python benches/bench_cli_start.py --exit

Each turn starts a fresh interpreter per tree and command, with ``PYTHONPATH`` at the tree's
``python/`` folder, runs what the installed ``granseg`` command runs, and times it to its
exit (the command's whole wall time, as a user waits for it). Trees take turns so that a
machine that slows down for a minute slows each alike; the table gives each tree's least and
most over the turns. ``--exit`` times instead how long the
last two commands take to exit once ``main`` has returned, as Python exits and with the heap
frozen first (what ``granseg.cli.console`` does).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMANDS = {
    "granseg --help": ["--help"],
    "granseg simulate --help": ["simulate", "--help"],
    "granseg diagnose --help": ["diagnose", "--help"],
    "granseg init-experiment (4 frames)": ["init-experiment", "{tmp}/frames", "--force", "--no-preview"],
    "granseg simulate (defaults)": ["simulate", "--out", "{tmp}/map", "--force"],
    "granseg analyze (a 4-frame fixture)": ["analyze", "{tree}/tests/fixtures/pbr/pom-pp", "--out", "{tmp}/a.npz",
                                            "--force", "--no-progress"],
}


def _sources(tree: Path) -> dict[str, str]:
    """The environment of a child that imports granseg from ``tree``'s sources."""
    return {**os.environ, "PYTHONPATH": str(tree / "python")}


def seconds(tree: Path, argv: list[str]) -> float:
    """Wall time [s] of ``granseg argv`` run from ``tree``'s sources; a failure stops the bench."""
    # what the installed `granseg` runs: console() where the tree has it (main() before 2026-11-30)
    code = "import sys, granseg.cli as cli; sys.exit(getattr(cli, 'console', cli.main)())"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code, *argv], env=_sources(tree), check=True, capture_output=True)
    return time.perf_counter() - t0


def exit_seconds(tree: Path, argv: list[str], freeze: bool) -> float:
    """Seconds from ``main`` returning to the process's end, with the heap frozen first or not."""
    code = ("import gc, sys, time, granseg.cli as cli\n"
            "freeze = sys.argv.pop(1) == 'freeze'\n"
            "rc = cli.main(sys.argv[1:])\n"
            "print('RETURNED', time.time(), file=sys.stderr, flush=True)\n"
            "if freeze:\n    gc.freeze()\n"
            "sys.exit(rc)\n")
    r = subprocess.run([sys.executable, "-c", code, "freeze" if freeze else "as-is", *argv], env=_sources(tree), check=True,
                       capture_output=True, text=True)
    ended = time.time()
    return ended - float(next(line.split()[1] for line in r.stderr.splitlines() if line.startswith("RETURNED")))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trees", nargs="+", type=Path, default=[Path(".")], help="source trees to compare")
    ap.add_argument("--turns", type=int, default=4)
    ap.add_argument("--exit", action="store_true",
                    help="instead: the exit alone (after main returns), as Python does it and with the heap frozen")
    args = ap.parse_args()
    if args.exit:
        with tempfile.TemporaryDirectory() as tmp:
            for name, argv in list(COMMANDS.items())[-2:]:
                argv = [a.format(tmp=tmp, tree=args.trees[0]) for a in argv]
                both = {f: [exit_seconds(args.trees[0], argv, f) for _ in range(args.turns)] for f in (False, True)}
                print(f"{name}: exit {min(both[False]):.2f}-{max(both[False]):.2f} s as Python does it, "
                      f"{min(both[True]):.2f}-{max(both[True]):.2f} s with the heap frozen")
        return
    times: dict[tuple[str, Path], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "frames").mkdir()  # a recording without its experiment.json yet
        for frame in sorted((args.trees[0] / "tests/fixtures/pbr/pom-pp").glob("frame_*")):
            shutil.copy(frame, Path(tmp) / "frames")
        for turn in range(args.turns):
            for name, argv in COMMANDS.items():
                for tree in args.trees:
                    t = seconds(tree, [a.format(tmp=tmp, tree=tree) for a in argv])
                    times.setdefault((name, tree), []).append(t)
            print(f"turn {turn + 1} of {args.turns} done", file=sys.stderr, flush=True)
    print("| command | " + " | ".join(str(t) for t in args.trees) + " |")
    print("|---|" + "---|" * len(args.trees))
    for name in COMMANDS:
        cells = [f"{min(times[name, t]):.2f}-{max(times[name, t]):.2f} s" for t in args.trees]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
