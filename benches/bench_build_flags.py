"""What the build flags cost: the solver's criterion benchmarks under three builds, in one run.

    python benches/bench_build_flags.py --out benches/results/build_flags.md

Builds the criterion benchmark ``solver`` three times, each into its own target folder
(``target/flags-*``), and runs the single-run and flux benchmarks of each:

- ``portable``: the default build (no CPU-specific instructions, no LTO), what ./dev.sh makes;
- ``native``: ``-C target-cpu=native`` (``GRANSEG_NATIVE=1 ./dev.sh ...``): this machine only;
- ``portable + thin LTO``: the release profile before issue 13 (minus native).

The three are run one after another, twice in alternating order, and the faster of each
build's two medians is kept: a busy machine slows whichever build it happens to meet.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCHES = "rhs_180_cells|gpp_3600s_every_2s_180_cells|gpp_3600s_no_outputs_180_cells"
BUILDS = {
    "portable": {},
    "native": {"RUSTFLAGS": "-C target-cpu=native"},
    "portable + thin LTO": {"CARGO_PROFILE_RELEASE_LTO": "thin"},
}
UNITS = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}


def _run(name: str, extra: dict[str, str]) -> dict[str, float]:
    env = {**os.environ, **extra, "CARGO_TARGET_DIR": str(ROOT / "target" / f"flags-{name.split()[0]}"
                                                       f"{'-lto' if 'LTO' in name else ''}")}
    cmd = ["cargo", "bench", "--profile", "release", "--bench", "solver", "--", "--noplot", BENCHES]
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout
    times = {}
    for bench, mid, unit in re.findall(r"^(\S+)\s+time:\s+\[\S+ \S+ (\S+) (\S+) \S+ \S+\]", out, re.M):
        times[bench] = float(mid) * UNITS[unit]
    if not times:
        raise RuntimeError(f"no criterion times in the output of {name}:\n{out[-2000:]}")
    return times


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="markdown table to write")
    a = p.parse_args(argv)
    best: dict[str, dict[str, float]] = {}
    order = list(BUILDS)
    for rep, names in enumerate((order, order[::-1]), 1):
        for name in names:
            t0 = time.perf_counter()
            times = _run(name, BUILDS[name])
            for bench, t in times.items():
                best.setdefault(name, {})[bench] = min(t, best.get(name, {}).get(bench, float("inf")))
            print(f"[round {rep}] {name}: built and run in {time.perf_counter() - t0:.0f} s", flush=True)
    benches = sorted({b for t in best.values() for b in t})
    load = os.getloadavg()
    lines = [f"Load average at the end: {load[0]:.2f} (1 min), {load[1]:.2f} (5 min); {os.cpu_count()} cores.",
             "", "| build | " + " | ".join(f"`{b}`" for b in benches) + " |",
             "|---|" + "---|" * len(benches)]
    ref = best["portable"]
    for name in order:
        cells = [f"{best[name][b] * 1e3:.3g} ms ({best[name][b] / ref[b]:.2f}x)" if best[name][b] >= 1e-4
                 else f"{best[name][b] * 1e6:.3g} us ({best[name][b] / ref[b]:.2f}x)" for b in benches]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    tmp = a.out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(a.out)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
