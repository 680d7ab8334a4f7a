"""Run a small DEM campaign with the example bed and turn it into granseg campaigns.

    python examples/dem/campaign.py OUT [--ratios 1.5 2 3 4] [--loads 150 600] [--steps 1200000]

Every (density ratio, lid load) pair is one LAMMPS run of ``shear_cell.in`` (``lmp`` from
Debian's ``lammps`` package), as many at once as the machine has cores, each logged when it
ends. Then every run is read back (:mod:`granseg.dem`) into

    OUT/campaign/bulk/NAME.npz       every grain per layer: a campaign directory
    OUT/campaign/wall/NAME.npz       the grains touching a side wall (the camera's view)
    OUT/campaign/velocity/NAME.json  the run's velocity profile
    OUT/costs.json                   each run's grains, steps, wall time and steps/s

A run already finished in OUT/runs is not run again, so an interrupted campaign resumes.
Defaults: a bed 11 grains high between the plate and the lid, 15 x 12 grains across (about
2,260 grains), c0 = 0.47, the plate at 4 (lj speed units, 0.97 m/s), lid forces 150 and 600
(46 and 186 Pa), 1.2 million sheared steps (8.9 s of the experiment's time). A gap of 12
grains between the side walls lets the whole bed shear; at 6 grains the walls' friction holds
its upper half still and the bed barely un-mixes.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="campaign folder (runs/, campaign/, costs.json)")
    p.add_argument("--ratios", type=float, nargs="+", default=[1.5, 2.0, 3.0, 4.0], help="heavy / light densities")
    p.add_argument("--loads", type=float, nargs="+", default=[150.0, 600.0],
                   help="total lid force, lj units (1 = 2.0e-3 N)")
    p.add_argument("--c0", type=float, default=0.47, help="heavy share of the bed (heavy on top at the start)")
    p.add_argument("--steps", type=int, default=1_200_000, help="sheared steps per run")
    p.add_argument("--dump-every", type=int, default=20_000, help="steps between snapshots")
    p.add_argument("--size", type=float, nargs=3, default=[15, 12, 11], metavar=("LX", "LY", "LAYERS"),
                   help="box length along the flow, gap between the side walls, bed layers (grain diameters)")
    p.add_argument("--U", type=float, default=4.0, help="plate speed, lj units (1 = 0.243 m/s)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="runs at once (default: all cores)")
    return p.parse_args(argv)


def _name(ratio: float, load: float) -> str:
    return f"dem-r{ratio:g}-F{load:g}"


def _run_one(lmp: str, run_dir: Path, var: dict[str, object]) -> dict[str, float]:
    """One LAMMPS run into ``run_dir`` (skipped if it finished before); its cost."""
    done = run_dir / "finished.json"
    if done.is_file():
        return json.loads(done.read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    args = [lmp, "-in", str(HERE / "shear_cell.in"), "-log", str(run_dir / "log.lammps"), "-screen", "none",
            "-var", "out", str(run_dir)]
    for k, v in var.items():
        args += ["-var", k, str(v)]
    start = time.perf_counter()
    subprocess.run(args, check=True, cwd=run_dir)
    log = (run_dir / "log.lammps").read_text()
    speeds = [float(s) for s in re.findall(r"Performance: .*?, ([\d.]+) timesteps/s", log)]
    grains = int(re.search(r"granseg shear cell: (\d+) grains", log).group(1))
    cost = {"grains": grains, "steps": int(var["steps"]) + int(var["settle_steps"]),
            "wall_s": time.perf_counter() - start, "sheared_steps_per_s": speeds[-1]}
    done.write_text(json.dumps(cost))
    return cost


def main(argv: list[str] | None = None) -> int:
    a = _args(argv)
    a.out = a.out.resolve()
    lmp = shutil.which("lmp")
    if lmp is None:
        print("error: LAMMPS (lmp) not found; on Debian: apt-get install lammps", file=sys.stderr)
        return 2
    Lx, Ly, layers = a.size
    runs = {_name(r, f): {"ratio": r, "load": f, "c0": a.c0, "steps": a.steps, "dump_every": a.dump_every,
                          "Lx": Lx, "Ly": Ly, "layers": layers, "U": a.U, "seed": a.seed, "settle_steps": 30000,
                          "thermo_every": 20000}
            for r in a.ratios for f in a.loads}
    a.out.mkdir(parents=True, exist_ok=True)
    costs: dict[str, dict[str, float]] = {}
    print(f"{len(runs)} runs, {a.jobs} at once", flush=True)
    with ThreadPoolExecutor(max_workers=a.jobs) as pool:
        futures = {pool.submit(_run_one, lmp, a.out / "runs" / n, v): n for n, v in runs.items()}
        for k, fut in enumerate(as_completed(futures), 1):
            name = futures[fut]
            costs[name] = fut.result()
            c = costs[name]
            print(f"[{k}/{len(runs)}] {name}: {c['grains']} grains, {c['wall_s']:.0f} s, "
                  f"{c['sheared_steps_per_s']:.0f} sheared steps/s", flush=True)
    (a.out / "costs.json").write_text(json.dumps(dict(sorted(costs.items())), indent=1))

    from granseg.dem.run import load_run, write_products

    products = {}
    for k, name in enumerate(sorted(runs), 1):
        run = load_run(a.out / "runs" / name, name=name)
        products.update(run.products(("bulk", "wall")))
        print(f"[{k}/{len(runs)}] read {name}: {len(run.snapshots)} snapshots, {run.n_layers} layers", flush=True)
    for path in write_products(a.out / "campaign", products, force=True):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
