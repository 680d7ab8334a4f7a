"""The whole chain on a DEM campaign: diagnose each view of the campaign that
``examples/dem/campaign.py`` made, and tabulate what the baseline gets wrong.

    python examples/dem/campaign.py /tmp/dem                     # the runs (LAMMPS) and their maps
    python benches/bench_dem_chain.py /tmp/dem/campaign --out benches/results/dem_chain.json

For each view (``bulk``: every grain; ``wall``: the grains at the side walls) the table gives the
maps that failed their window check, the baseline's calibrated k and delta/H, its mean RMSD
against the counting-noise floor, the best extension's RMSD and held-out gain, and the
departures the diagnosis names (catalogued cause and open-world laws). Flagged maps are
diagnosed anyway (``accept_flagged``): the point is to see what the chain makes of them.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from granseg._io import save_json
from granseg.calibration import calibrate
from granseg.diagnosis import diagnose
from granseg.maps import load_campaign

VIEWS = ("bulk", "wall")


def _row(view: str, folder: Path, n_cells: int) -> dict:
    maps = load_campaign(folder).maps
    start = time.perf_counter()
    r = diagnose(folder, n_cells=n_cells, progress=False, accept_flagged=True).result
    ext = r.get("extended") or {}
    dep = r.get("departure") or {}
    best_cause = max(r["candidates"], key=lambda c: c["gain_held_out"], default=None)
    scored = [law for law in ((r.get("open_world") or {}).get("laws") or []) if law["gain_held_out"] is not None]
    best_law = max(scored, key=lambda law: law["gain_held_out"], default=None)
    return {
        "view": view, "maps": len(maps), "layers": sorted({m.n_layers for m in maps}),
        "flagged": [m.name for m in maps if m.failed_checks],
        "k": r["baseline"]["params"]["k"], "delta_over_H": r["baseline"]["params"]["delta_over_H"],
        "noise_floor": r["noise_floor"], "baseline_rmsd": r["baseline"]["rmsd_mean"],
        "baseline_rmsd_held_out": r["baseline"]["rmsd_held_out_mean"],
        "extended": ext.get("model"), "extended_rmsd": ext.get("rmsd_mean"),
        "gain_held_out": r["gain"]["rmsd_held_out"], "cause": r["cause"], "explained": r["explained"],
        "departure": dep.get("law"), "departure_summary": dep.get("summary"), "summary": r["summary"],
        "best_cause": best_cause and {k: best_cause[k] for k in ("name", "rmsd", "rmsd_held_out", "gain_held_out")},
        "best_law": best_law and {k: best_law[k] for k in ("law", "rmsd", "rmsd_held_out", "gain_held_out")},
        "seconds": time.perf_counter() - start,
    }


def _markdown(rows: list[dict]) -> str:
    head = ("| view | maps (layers) | flagged by the window check | k | delta/H | noise floor | baseline RMSD "
            "(held out) | best catalogue cause: RMSD, held-out gain | best law correction: RMSD, held-out gain "
            "| verdict |\n|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        named = ", ".join([r["cause"]] + [f"law {r['departure']}"] * bool(r["departure"]))
        cause = (f"{r['best_cause']['name']}: {r['best_cause']['rmsd']:.4f}, {r['best_cause']['gain_held_out']:+.4f}"
                 if r["best_cause"] else "not tried")
        law = (f"{r['best_law']['law']}: {r['best_law']['rmsd']:.4f}, {r['best_law']['gain_held_out']:+.4f}"
               if r["best_law"] else "not tried")
        lines.append(f"| {r['view']} | {r['maps']} ({', '.join(map(str, r['layers']))}) | {len(r['flagged'])} "
                     f"| {r['k']:.3f} | {r['delta_over_H']:.3f} | {r['noise_floor']:.4f} "
                     f"| {r['baseline_rmsd']:.4f} ({r['baseline_rmsd_held_out']:.4f}) | {cause} | {law} | {named} |")
    return head + "\n".join(lines) + "\n"


#: calibrations of the bulk view besides the baseline's k and delta/H: (label, calibrate keywords)
CALIBRATIONS = (
    ("k, delta/H fitted (the baseline)", {}),
    ("k fitted; each run's measured band, exponential fit", {"velocity": "velocity", "velocity_shape": "exponential"}),
    ("k fitted; each run's measured shear rate, tabulated", {"velocity": "velocity", "velocity_shape": "tabulated"}),
    ("k, delta/H and b fitted, wide bounds", {"grid": {"k": [0.5, 1.0, 1.5], "delta_over_H": [0.15, 0.25, 0.35],
                                                      "b": [0.02, 0.05, 0.1]}, "bounds": {"k": (0.2, 5.0)}}),
)


def _calibrations(campaign: Path, n_cells: int) -> list[dict]:
    rows = []
    for label, kw in CALIBRATIONS:
        kw = {**kw, **({"velocity": campaign / kw["velocity"]} if "velocity" in kw else {})}
        with warnings.catch_warnings():  # parameters on their bounds are the finding here
            warnings.simplefilter("ignore")
            c = calibrate(campaign / "bulk", n_cells=n_cells, progress=False, **kw)
        rows.append({"calibration": label, "best": c.best, "rmsd_mean": c.rmsd_mean, "at_bound": c.at_bound})
        print(f"calibration: {label}: RMSD {c.rmsd_mean:.4f}", flush=True)
    return rows


def _calibration_markdown(rows: list[dict], floor: float) -> str:
    head = f"| bulk view, calibrated | parameters | mean RMSD (noise floor {floor:.4f}) |\n|---|---|---|\n"
    return head + "\n".join(
        f"| {r['calibration']} | " + ", ".join(f"{k} = {v:.3g}" + (" (bound)" if k in r["at_bound"] else "")
                                              for k, v in r["best"].items())
        + f" | {r['rmsd_mean']:.4f} |" for r in rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("campaign", type=Path, help="the campaign folder (with bulk/ and wall/)")
    p.add_argument("--out", type=Path, required=True, help="JSON to write (and a .md beside it)")
    p.add_argument("--n-cells", type=int, default=72)
    p.add_argument("--force", action="store_true")
    a = p.parse_args(argv)
    rows = []
    for k, view in enumerate(VIEWS, 1):
        rows.append(_row(view, a.campaign / view, a.n_cells))
        print(f"[{k}/{len(VIEWS)}] {view}: {rows[-1]['summary']}", flush=True)
    cals = _calibrations(a.campaign, a.n_cells)
    save_json(a.out, {"campaign": str(a.campaign), "rows": rows, "calibrations": cals}, force=a.force)
    md = _markdown(rows) + "\n" + _calibration_markdown(cals, rows[0]["noise_floor"])
    a.out.with_suffix(".md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
