"""How soon Ctrl-C stops a long run, and what the run had touched by then.

    PYTHONPATH=python python benches/bench_interrupt.py [--waits 0.1 0.3 1 2 4] [--cli-waits 0.1 0.5 3 5]

Each measurement is a fresh interpreter that starts the largest full-field run
the core accepts in one call (1801 output times x 100 000 cells, a 1.44 GB
field, rtol 1e-10), is sent SIGINT ``wait`` seconds after it begins, and
reports:

* ``granseg.simulate``: seconds from the signal to the KeyboardInterrupt it
  raises, and the process's peak resident memory at that moment;
* ``granseg simulate`` (the command line): seconds from the signal to the
  process's exit, its exit code (130 is "interrupted") and whether a traceback
  was printed. The command's first second or so is spent importing the
  commands' modules, so the smallest waits land there.

``--random N`` then sends the command's SIGINT at N moments drawn uniformly
from 0.1-4.5 s (``--seed``), with ``--load`` another process keeping one core
busy meanwhile, and counts the exit codes, the tracebacks and the longest time
to exit (a run that has not ended 120 s after its signal is counted as hung).

Compare two trees by running this with each one's ``python/`` on PYTHONPATH
(and its built core), taking turns (BENCHMARKS.md "Ctrl-C at any moment").
"""

from __future__ import annotations

import argparse
import collections
import os
import random
import signal
import subprocess
import sys
import textwrap
import time

RUN = "t=[2.0 * i for i in range(1801)], n_cells=100_000, rtol=1e-10, atol=1e-12"

# SIGINT handled as under a terminal: a script's background job hands its children SIGINT
# ignored, and a Python started so never installs the handler that raises KeyboardInterrupt
AS_IN_A_TERMINAL = "import signal\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"

# the peak memory is VmHWM, this process's own since it started (Linux); ru_maxrss would also
# count the parent's memory at the fork
API = AS_IN_A_TERMINAL + textwrap.dedent(f"""
    import re, time
    import granseg
    print("go", flush=True)
    try:
        granseg.simulate({RUN}, field=True)
    except KeyboardInterrupt:
        with open("/proc/self/status") as f:
            print(time.time(), re.search(r"VmHWM:\\s*(\\d+) kB", f.read()).group(1), flush=True)
""")

CLI = AS_IN_A_TERMINAL + textwrap.dedent("""
    import sys
    from granseg.cli import main
    print("go", flush=True)
    sys.exit(main(["simulate", "--n-cells", "100000", "--rtol", "1e-10", "--atol", "1e-12",
                   "--out", sys.argv[1], "--force"]))
""")


def interrupted(code: str, wait: float, *args: str) -> tuple[float, subprocess.CompletedProcess]:
    """Run ``code`` (which prints 'go' first), SIGINT it ``wait`` s later; the signal's time and the result."""
    pr = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True)
    try:
        if pr.stdout.readline().strip() != "go":
            raise RuntimeError(pr.stderr.read())
        time.sleep(wait)
        sent = time.time()
        os.kill(pr.pid, signal.SIGINT)
        out, err = pr.communicate(timeout=120)
        return sent, subprocess.CompletedProcess(pr.args, pr.returncode, out, err)
    finally:
        if pr.poll() is None:
            pr.kill()
            pr.communicate()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--waits", type=float, nargs="+", default=[0.1, 0.3, 0.6, 1.0, 2.0, 4.0])
    ap.add_argument("--cli-waits", type=float, nargs="+", default=[0.1, 0.5, 1.0, 3.0, 5.0])
    ap.add_argument("--out", default="/tmp/granseg-bench-interrupt", help="the command's figure path (never written)")
    ap.add_argument("--random", type=int, default=0, metavar="N", help="also N command-line interrupts at random moments")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--load", action="store_true", help="keep one core busy during the random interrupts")
    args = ap.parse_args()
    print("granseg.simulate, 1801 times x 100 000 cells:")
    for wait in args.waits:
        sent, r = interrupted(API, wait)
        if r.returncode != 0:
            raise RuntimeError(f"SIGINT at {wait} s: exit {r.returncode}\n{r.stderr}")
        raised, rss_kb = r.stdout.split()[-2:]
        print(f"  SIGINT at {wait:4.1f} s: KeyboardInterrupt {float(raised) - sent:6.3f} s later, "
              f"peak memory {int(rss_kb) / 1024:6.0f} MB", flush=True)
    print("granseg simulate --n-cells 100000 (command line):")
    for wait in args.cli_waits:
        sent, r = interrupted(CLI, wait, args.out)
        took = time.time() - sent
        print(f"  SIGINT at {wait:4.1f} s: exit {r.returncode:4d} {took:6.2f} s later, "
              f"{'a traceback' if 'Traceback' in r.stderr else 'one line'} on stderr", flush=True)
    if args.random:
        random_interrupts(args)


def random_interrupts(args: argparse.Namespace) -> None:
    """The command line interrupted at ``args.random`` random moments; a summary line."""
    rng = random.Random(args.seed)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if args.load else None
    codes, tracebacks, longest = collections.Counter(), 0, 0.0
    try:
        for _ in range(args.random):
            try:
                sent, r = interrupted(CLI, rng.uniform(0.1, 4.5), args.out)
            except subprocess.TimeoutExpired:
                codes["hung (killed after 120 s)"] += 1
                continue
            longest = max(longest, time.time() - sent)
            codes[r.returncode] += 1
            tracebacks += "Traceback" in r.stderr
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    print(f"{args.random} interrupts at random moments of 0.1-4.5 s{' (one core kept busy)' if busy else ''}: "
          f"exit codes {dict(codes)}, {tracebacks} tracebacks, longest {longest:.2f} s to exit")


if __name__ == "__main__":
    main()
