"""Side-by-side solver benchmarks behind BENCHMARKS.md (issue 2).

    python benches/compare_scipy.py [--repeats 15] [--out benches/results/solver.md]

1. One G-PP run (c0 = 0.5, 3600 s, outputs every 2 s, 180 cells): granseg
   against the scipy method-of-lines reference (tests/reference_mol.py,
   solve_ivp BDF with a banded Jacobian sparsity), each at the loosest
   tolerance of a ladder whose 15-layer map is within 1e-3 of a refined
   solution (granseg at 1440 cells, rtol 1e-8). Best-of-N wall times, one
   process, one run: the ratio is what counts on a noisy machine.
2. The paper's 3 x 3 factorial for three cases (27 runs) as one sweep, with
   1 and 2 threads.
3. Peak memory (max RSS) of a fresh process that runs that sweep.

With ``--grids`` it also lets each solver choose its grid: every (cells,
tolerance) pair of a ladder is run, and each solver's fastest pair whose
15-layer map meets 1e-3 is compared (does a coarser grid close the gap to
the 100x goal of issue 15?).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import granseg  # noqa: E402
from reference_mol import Reference  # noqa: E402

T = np.arange(0, 3601, 2.0)
GPP = dict(rho_h=2450.0, rho_l=946.0, c0=0.5)
TARGET = 1e-3
PAPER_CASES = [dict(rho_h=3500.0, rho_l=946.0, c0=0.5), dict(rho_h=2450.0, rho_l=946.0, c0=0.5),
               dict(rho_h=2450.0, rho_l=1750.0, c0=0.5)]
PAPER_GRID = {"k": [0.5, 0.6, 0.7], "delta_over_H": [0.18, 0.20, 0.22]}


def best_time(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def loosest(ladder, error_of):
    """First (loosest) setting of the ladder whose error meets TARGET."""
    for setting in ladder:
        err = error_of(setting)
        if err <= TARGET:
            return setting, err
    raise RuntimeError("no setting of the ladder meets the accuracy target")


def single_run(repeats: int) -> dict:
    ref = granseg.simulate(**GPP, t=T, n_cells=1440, rtol=1e-8, atol=1e-10).layers()
    ours_ladder = [(3e-4, 3e-5), (1e-4, 1e-5), (3e-5, 3e-6), (1e-5, 1e-6)]
    (rt, at), err_ours = loosest(
        ours_ladder, lambda s: np.abs(granseg.simulate(**GPP, t=T, rtol=s[0], atol=s[1]).layers() - ref).max())
    mol = Reference(GPP["rho_h"], GPP["rho_l"], GPP["c0"], n=180)
    sp_ladder = [(1e-3, 1e-5), (1e-3, 3e-6), (1e-3, 1e-6), (3e-4, 1e-6), (1e-4, 1e-7)]
    (srt, sat), err_sp = loosest(sp_ladder, lambda s: np.abs(mol.layers(mol.solve(T, s[0], s[1])) - ref).max())
    mol.n_rhs = 0
    mol.solve(T, srt, sat)
    sp_rhs = mol.n_rhs
    # what a user calls: the run and its 15 camera layers (issue 15), both solvers alike
    t_ours = best_time(lambda: granseg.simulate(**GPP, t=T, rtol=rt, atol=at).layers(), repeats)
    t_field = best_time(lambda: granseg.simulate(**GPP, t=T, rtol=rt, atol=at, field=True).layers(), repeats)
    t_sp = best_time(lambda: mol.layers(mol.solve(T, srt, sat)), max(3, repeats // 3))
    stats = granseg.simulate(**GPP, t=T, rtol=rt, atol=at).stats
    default_err = np.abs(granseg.simulate(**GPP, t=T).layers() - ref).max()
    t_default = best_time(lambda: granseg.simulate(**GPP, t=T).layers(), repeats)
    return dict(ours=(rt, at, err_ours, t_ours, stats), scipy=(srt, sat, err_sp, t_sp, sp_rhs),
                default=(default_err, t_default), field=t_field)


GRID_CELLS = (45, 60, 90, 120, 180)


def grid_ladder(repeats: int) -> str:
    """Each solver's fastest (cells, tolerance) meeting TARGET, every pair tried, as a markdown table."""
    ref = granseg.simulate(**GPP, t=T, n_cells=1440, rtol=1e-8, atol=1e-10).layers()
    rows = []
    for n in GRID_CELLS:
        for rt in (1e-3, 3e-4, 1e-4):
            run = lambda n=n, rt=rt: granseg.simulate(**GPP, t=T, n_cells=n, rtol=rt, atol=rt / 10).layers()  # noqa: E731
            rows.append(("granseg", n, f"rtol {rt:g}, atol {rt / 10:g}", np.abs(run() - ref).max(),
                         best_time(run, repeats)))
        mol = Reference(GPP["rho_h"], GPP["rho_l"], GPP["c0"], n=n)
        for rt, at in ((1e-3, 1e-5), (1e-3, 3e-6), (3e-4, 1e-6)):
            run = lambda mol=mol, rt=rt, at=at: mol.layers(mol.solve(T, rt, at))  # noqa: E731
            rows.append(("scipy", n, f"rtol {rt:g}, atol {at:g}", np.abs(run() - ref).max(),
                         best_time(run, max(3, repeats // 3))))
    best = {who: min((r for r in rows if r[0] == who and r[3] <= TARGET), key=lambda r: r[4])
            for who in ("granseg", "scipy")}
    lines = ["| solver | cells | tolerances | layer error | wall time |", "|---|---|---|---|---|"]
    lines += [f"| {who} | {n} | {tol} | {err:.1e} | {t * 1e3:.2f} ms |" for who, n, tol, err, t in rows]
    g, s = best["granseg"], best["scipy"]
    lines += ["", f"Fastest within {TARGET:g}: granseg {g[1]} cells ({g[2]}) {g[4] * 1e3:.2f} ms, "
              f"scipy {s[1]} cells ({s[2]}) {s[4] * 1e3:.1f} ms: **{s[4] / g[4]:.0f}x**."]
    return "\n".join(lines) + "\n"


def paper_sweep(repeats: int) -> dict:
    t = {}
    for threads in (1, 2):
        t[threads] = best_time(lambda th=threads: granseg.sweep(PAPER_GRID, cases=PAPER_CASES, t=T, threads=th),
                               repeats)
    return t


MEMORY_SNIPPET = """
import resource, numpy as np, granseg
from benches_compare import PAPER_GRID, PAPER_CASES, T
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
res = granseg.sweep(PAPER_GRID, cases=PAPER_CASES, t=T)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(before / 1024, after / 1024, res.layers.nbytes / 2**20)
"""


def peak_memory() -> tuple[float, float, float]:
    code = MEMORY_SNIPPET.replace("from benches_compare import PAPER_GRID, PAPER_CASES, T",
                                  f"PAPER_GRID = {PAPER_GRID!r}\nPAPER_CASES = {PAPER_CASES!r}\n"
                                  "T = np.arange(0, 3601, 2.0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, after, arrays = (float(x) for x in out.stdout.split())
    return before, after, arrays


def report(single: dict, sweep_t: dict, mem: tuple[float, float, float]) -> str:
    rt, at, e1, t1, stats = single["ours"]
    srt, sat, e2, t2, sp_rhs = single["scipy"]
    d_err, d_t = single["default"]
    lines = [
        "| solver (G-PP, 3600 s, 1801 outputs, 180 cells), the run and its 15 layers | tolerances | layer error "
        "| wall time | ratio |",
        "|---|---|---|---|---|",
        f"| scipy solve_ivp BDF, banded Jacobian sparsity | rtol {srt:g}, atol {sat:g} | {e2:.1e} "
        f"| {t2 * 1e3:.1f} ms ({sp_rhs} RHS evaluations) | 1 |",
        f"| `granseg.simulate(...).layers()` (ESDIRK3, Rust; layers made while stepping) | rtol {rt:g}, "
        f"atol {at:g} | {e1:.1e} | {t1 * 1e3:.2f} ms "
        f"({stats['steps']} steps, {stats['rhs_evals']} flux evaluations) | **{t2 / t1:.0f}x** |",
        f"| the same with `field=True` (the 1801 x 180 field built, then reduced) | rtol {rt:g}, atol {at:g} "
        f"| {e1:.1e} | {single['field'] * 1e3:.2f} ms | {t2 / single['field']:.0f}x |",
        f"| granseg, default tolerances | rtol {granseg.model.RTOL:g}, atol {granseg.model.ATOL:g} | {d_err:.1e} "
        f"| {d_t * 1e3:.2f} ms | {t2 / d_t:.0f}x |",
        "",
        "| paper factorial, 27 runs, one sweep | wall time |",
        "|---|---|",
        f"| 1 thread | {sweep_t[1] * 1e3:.0f} ms |",
        f"| 2 threads | {sweep_t[2] * 1e3:.0f} ms (speed-up {sweep_t[1] / sweep_t[2]:.2f}x) |",
        "",
        f"Peak memory (max RSS) of a fresh process running the 27-run sweep: {mem[1]:.0f} MB "
        f"({mem[0]:.0f} MB after importing granseg and numpy; result arrays {mem[2]:.1f} MB).",
    ]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--out", type=Path, help="also write the markdown table here (atomic, overwrites)")
    ap.add_argument("--grids", action="store_true", help="only the grid ladder: each solver picks its cells")
    args = ap.parse_args()
    if args.grids:
        text = grid_ladder(args.repeats)
    else:
        single = single_run(args.repeats)
        sweep_t = paper_sweep(max(3, args.repeats // 3))
        text = report(single, sweep_t, peak_memory())
    print(text)
    if args.out:
        from granseg._io import atomic_write

        atomic_write(args.out, lambda p: p.write_text(text), force=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
