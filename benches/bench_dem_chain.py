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
from pathlib import Path

from granseg._io import save_json
from granseg.diagnosis import diagnose
from granseg.maps import load_campaign

VIEWS = ("bulk", "wall")


def _row(view: str, folder: Path, n_cells: int) -> dict:
    maps = load_campaign(folder).maps
    start = time.perf_counter()
    r = diagnose(folder, n_cells=n_cells, progress=False, accept_flagged=True).result
    ext = r.get("extended") or {}
    dep = r.get("departure") or {}
    return {
        "view": view, "maps": len(maps), "layers": sorted({m.n_layers for m in maps}),
        "flagged": [m.name for m in maps if m.failed_checks],
        "k": r["baseline"]["params"]["k"], "delta_over_H": r["baseline"]["params"]["delta_over_H"],
        "noise_floor": r["noise_floor"], "baseline_rmsd": r["baseline"]["rmsd_mean"],
        "baseline_rmsd_held_out": r["baseline"]["rmsd_held_out_mean"],
        "extended": ext.get("model"), "extended_rmsd": ext.get("rmsd_mean"),
        "gain_held_out": r["gain"]["rmsd_held_out"], "cause": r["cause"], "explained": r["explained"],
        "departure": dep.get("law"), "departure_summary": dep.get("summary"), "summary": r["summary"],
        "seconds": time.perf_counter() - start,
    }


def _markdown(rows: list[dict]) -> str:
    head = ("| view | maps (layers) | flagged by the window check | k | delta/H | noise floor | baseline RMSD "
            "| extended RMSD | held-out gain | named departures |\n|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        named = ", ".join([r["cause"]] * (r["cause"] not in ("none", "unexplained"))
                          + [f"law {r['departure']}"] * bool(r["departure"])) or r["cause"]
        ext = f"{r['extended_rmsd']:.4f} ({r['extended']})" if r["extended_rmsd"] is not None else "-"
        lines.append(f"| {r['view']} | {r['maps']} ({', '.join(map(str, r['layers']))}) | {len(r['flagged'])} "
                     f"| {r['k']:.3f} | {r['delta_over_H']:.3f} | {r['noise_floor']:.4f} | {r['baseline_rmsd']:.4f} "
                     f"| {ext} | {r['gain_held_out']:+.4f} | {named} |")
    return head + "\n".join(lines) + "\n"


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
    save_json(a.out, {"campaign": str(a.campaign), "rows": rows}, force=a.force)
    md = _markdown(rows)
    a.out.with_suffix(".md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
