"""Benchmark: ``granseg report`` on campaigns of N small synthetic experiments (issue 14).

For each N a campaign of N small virtual experiments is made once
(:func:`granseg.synth.virtual.campaign`: Table-1 material pairs, c0 in
{0.25, 0.5, 0.75}, fill masses with a scatter, a few dozen frames, a coarse
model grid) and ``granseg report CAMPAIGN --out DIR`` runs on it in a fresh
subprocess. Its wall time and peak resident memory (``getrusage`` of the child,
``ru_maxrss``) are measured; ``--calibrate-only`` also times ``granseg
calibrate`` on the same campaign, the floor the report cannot go below.

    python benches/bench_report_scale.py --n 25 50 100 200 --out benches/results/report_scale.md
    python benches/bench_report_scale.py --n 50 --pythonpath /tmp/orig/python --label before

``--pythonpath`` chooses the granseg package the child imports (e.g. an
export of an older commit, to measure before and after a change); ``--label``
names the rows. With ``--out`` the markdown table is written (appended to,
when the file exists and ``--append``), with the command line at the top.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PAIRS = [("steel", "PP"), ("steel", "POM"), ("ceramic", "PP"), ("glass", "PP"), ("POM", "PP"), ("glass", "POM")]
C0S = (0.25, 0.5, 0.75)
REPORT_ARGS = ["--n-cells", "48", "--max-nfev", "4"]


def make_campaign(root: Path, n: int, seed: int = 0) -> Path:
    """A campaign folder of ``n`` small virtual experiments (made once, reused)."""
    out = root / f"campaign_{n}"
    if (out / "campaign.json").is_file():
        return out
    import numpy as np

    from granseg.synth.virtual import Condition, campaign, fill_mass

    rng = np.random.default_rng(seed)
    conds = []
    for i in range(n):
        heavy, light = PAIRS[i % len(PAIRS)]
        c0 = C0S[(i // len(PAIRS)) % len(C0S)]
        m_g = round(fill_mass(heavy, light, c0) * rng.uniform(0.97, 1.03), 3)
        short = {"steel": "S", "ceramic": "C", "glass": "G"}
        name = f"{short.get(heavy, heavy)}-{short.get(light, light)}-{round(100 * c0)}-{i:03d}"
        conds.append(Condition(heavy, light, c0, m_g, name=name))
    campaign(out, conditions=conds, seed=seed, noise="independent", fps=0.05, duration=2400.0, n_cells=48)
    return out


def run_child(argv: list[str], pythonpath: str | None) -> tuple[float, float, int, str]:
    """Run ``granseg ARGV`` in a fresh interpreter: (wall s, peak RSS MB, exit code, stderr tail).

    The child runs under a small launcher that reports its own ``ru_maxrss`` (the children
    of this process accumulate in RUSAGE_CHILDREN, whose maximum would mix the runs)."""
    launcher = ("import resource, sys\n"
                "from granseg.cli import main\n"
                "try:\n    rc = main(sys.argv[1:])\n"
                "finally:\n"
                "    print('MAXRSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
                "sys.exit(rc)\n")
    env = dict(os.environ, MPLBACKEND="Agg")
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", launcher, *argv], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    rss = next((int(line.split()[1]) for line in proc.stderr.splitlines() if line.startswith("MAXRSS_KB")), -1)
    return wall, rss / 1024.0, proc.returncode, proc.stderr[-600:]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[25, 50, 100, 200], help="campaign sizes")
    ap.add_argument("--work", default=None, help="folder for the campaigns and reports (default: a temp folder)")
    ap.add_argument("--pythonpath", default=None, help="PYTHONPATH of the child (the granseg to measure)")
    ap.add_argument("--label", default="", help="name of this set of rows (e.g. before / after)")
    ap.add_argument("--calibrate-only", action="store_true", help="also time `granseg calibrate` alone")
    ap.add_argument("--out", default=None, help="write the markdown table here")
    ap.add_argument("--append", action="store_true", help="append the rows to --out instead of replacing it")
    args = ap.parse_args()

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench_report_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in args.n:
        camp = make_campaign(work, n)
        out = work / f"report_{n}"
        shutil.rmtree(out, ignore_errors=True)
        wall, rss, rc, err = run_child(["report", str(camp), "--out", str(out), "-q", *REPORT_ARGS],
                                       args.pythonpath)
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6 if out.exists() else 0.0
        row = {"label": args.label, "n": n, "what": "report", "wall": wall, "rss": rss, "rc": rc, "mb": size}
        rows.append(row)
        print(f"{args.label} N={n} report: {wall:.1f} s, {rss:.0f} MB peak RSS, exit {rc}, {size:.1f} MB written",
              flush=True)
        if rc != 0:
            print(err, file=sys.stderr)
        if args.calibrate_only:
            wall, rss, rc, err = run_child(["calibrate", str(camp), "-q", *REPORT_ARGS], args.pythonpath)
            rows.append({"label": args.label, "n": n, "what": "calibrate", "wall": wall, "rss": rss, "rc": rc,
                         "mb": float("nan")})
            print(f"{args.label} N={n} calibrate: {wall:.1f} s, {rss:.0f} MB peak RSS, exit {rc}", flush=True)
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)

    head = "| code | N | command | wall [s] | peak RSS [MB] | exit | output [MB] |\n|---|---:|---|---:|---:|---:|---:|\n"
    body = "".join(f"| {r['label']} | {r['n']} | {r['what']} | {r['wall']:.1f} | {r['rss']:.0f} | {r['rc']} | "
                   + ("" if r["mb"] != r["mb"] else f"{r['mb']:.1f}") + " |\n" for r in rows)
    print("\n" + head + body)
    if args.out:
        out = Path(args.out)
        cmd = "python " + " ".join(shlex.quote(a) for a in sys.argv)
        if args.append and out.exists():
            out.write_text(out.read_text() + f"\n`{cmd}`\n\n" + head + body)
        else:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(f"# granseg report: time and memory against campaign size\n\n`{cmd}`\n\n"
                           f"report options: `{' '.join(REPORT_ARGS)}`; machine: {os.cpu_count()} cores\n\n"
                           + head + body)
    return 0 if all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
