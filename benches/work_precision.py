"""Work-precision diagram of the solvers (issue 15): error of the 15-layer map against a refined
solution, against wall time through the public API, for each solver over a ladder of tolerances.

    python benches/work_precision.py [--repeats 7] [--out benches/results/work_precision]

One G-PP run (glass/PP, c0 = 0.5, 3600 s, outputs every 2 s, 180 cells), the case of
compare_scipy.py. The reference is granseg at 1440 cells, rtol 1e-8. Each point is one
tolerance: x = best-of-N wall time of the call and its 15 layers, y = the largest layer error
over all outputs. At 180 cells the error cannot fall below the spatial error (the plateau on the
left of each curve); the time to reach a given error is what tells the solvers apart. Writes
OUT.png, OUT.pdf and OUT.md (the table), all from this one run of one process.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from compare_scipy import GPP, T, best_time  # noqa: E402  (the case and the timer, one definition)

import granseg  # noqa: E402
from reference_mol import Reference  # noqa: E402

RTOLS = [1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6]



def curves(repeats: int) -> dict[str, list[tuple[float, float, float]]]:
    """solver -> [(rtol, seconds, layer error)]."""
    ref = granseg.simulate(**GPP, t=T, n_cells=1440, rtol=1e-8, atol=1e-10).layers()
    out: dict[str, list[tuple[float, float, float]]] = {"granseg ESDIRK3 (default scheme)": []}
    for rt in RTOLS:
        run = lambda rt=rt: granseg.simulate(**GPP, t=T, rtol=rt, atol=rt / 10).layers()  # noqa: E731
        out["granseg ESDIRK3 (default scheme)"].append((rt, best_time(run, repeats), np.abs(run() - ref).max()))
        print(f"granseg rtol {rt:g}: {out['granseg ESDIRK3 (default scheme)'][-1][1] * 1e3:.2f} ms", flush=True)
    mol = Reference(GPP["rho_h"], GPP["rho_l"], GPP["c0"], n=180)
    for method in ("BDF", "Radau"):
        name = f"scipy solve_ivp {method}, banded Jacobian sparsity"
        out[name] = []
        for rt in RTOLS[:7]:  # tighter ones take seconds each and add nothing
            run = lambda rt=rt, m=method: mol.layers(mol.solve(T, rt, rt / 100, method=m))  # noqa: E731
            try:
                err = np.abs(run() - ref).max()
            except RuntimeError:
                continue
            out[name].append((rt, best_time(run, max(2, repeats // 3)), err))
            print(f"{name} rtol {rt:g}: {out[name][-1][1] * 1e3:.1f} ms", flush=True)
    return out


def table(data: dict[str, list[tuple[float, float, float]]]) -> str:
    lines = ["| solver | rtol | wall time | largest layer error |", "|---|---|---|---|"]
    for name, pts in data.items():
        lines += [f"| {name} | {rt:g} | {s * 1e3:.2f} ms | {e:.1e} |" for rt, s, e in pts]
    # the time each solver needs for 1e-3, the accuracy the defaults promise
    lines += ["", "| solver | fastest call with layer error <= 1e-3 |", "|---|---|"]
    fastest = {}
    for name, pts in data.items():
        ok = [s for _, s, e in pts if e <= 1e-3]
        fastest[name] = min(ok) if ok else float("nan")
        lines.append(f"| {name} | {fastest[name] * 1e3:.2f} ms |")
    g = fastest["granseg ESDIRK3 (default scheme)"]
    for name, s in fastest.items():
        if not name.startswith("granseg"):
            lines.append(f"\ngranseg is {s / g:.0f}x faster than {name} at equal accuracy (1e-3).")
    return "\n".join(lines) + "\n"


def figure(data: dict[str, list[tuple[float, float, float]]], stem: Path) -> None:
    from granseg.plot.base import new_figure, save_figure, style

    with style():
        fig = new_figure(6.0, 4.2)
        ax = fig.add_subplot()
        for (name, pts), marker in zip(data.items(), "os^D", strict=False):
            s = np.array([p[1] for p in pts]) * 1e3
            e = np.array([p[2] for p in pts])
            ax.loglog(s, e, marker=marker, label=name)
            last = None  # label a point only when it is clear of the last labelled one
            for rt, x, y in zip([p[0] for p in pts], s, e, strict=True):
                here = np.log10([x, y])
                if last is None or np.abs(here - last).max() > 0.3:
                    ax.annotate(f"{rt:g}", (x, y), textcoords="offset points", xytext=(4, 3), fontsize=7,
                                color="0.35")
                    last = here
        ax.axhline(1e-3, color="0.5", lw=0.8, ls="--")
        ax.annotate("1e-3: the accuracy the defaults promise", (0.33, 1e-3), xycoords=("axes fraction", "data"),
                    textcoords="offset points", xytext=(0, 3), fontsize=7, color="0.35")
        ax.set_xlabel("wall time of one call and its 15 layers [ms]")
        ax.set_ylabel("largest error of the 15-layer map [-]")
        ax.set_title("G-PP, 3600 s, 1801 outputs, 180 cells (labels: rtol)", loc="left", fontsize=9)
        ax.legend(fontsize=8, loc="upper right")
    save_figure(fig, stem, force=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", type=Path, help="stem for OUT.png, OUT.pdf, OUT.md (overwritten)")
    args = ap.parse_args()
    data = curves(args.repeats)
    text = "    python benches/work_precision.py " + " ".join(sys.argv[1:]) + "\n\n" + table(data)
    print(text)
    if args.out:
        from granseg._io import atomic_write

        atomic_write(args.out.with_suffix(".md"), lambda p: p.write_text(text), force=True)
        figure(data, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
