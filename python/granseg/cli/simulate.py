"""``granseg simulate``: one run of the model, a summary and a figure."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="run the segregation-diffusion model once",
        description="Solve the model of docs/model.md for one experiment, print a summary "
        "and write a figure (PNG + PDF). Densities in kg/m^3, times in s.",
    )
    mat = p.add_argument_group("materials (names from docs/model.md or densities)")
    mat.add_argument("--heavy", default="glass", help="heavy material name (default glass)")
    mat.add_argument("--light", default="PP", help="light material name (default PP)")
    mat.add_argument("--rho-h", type=float, help="heavy density, kg/m^3 (overrides --heavy)")
    mat.add_argument("--rho-l", type=float, help="light density, kg/m^3 (overrides --light)")
    p.add_argument("--c0", type=float, default=0.5, help="overall heavy fraction (default 0.5)")
    p.add_argument("--like", metavar="MAP.npz",
                   help="simulate the experiment of a map: its materials, c0, load, cell (docs/formats.md), layers and "
                        "times; prints the RMSD against it (--k, --delta-over-H, --set still apply)")
    p.add_argument("--k", type=float, help="friction correction k (default 0.70)")
    p.add_argument("--delta-over-H", type=float, dest="delta_over_H", help="shear band delta/H (default 0.18)")
    p.add_argument("--velocity", metavar="V.json",
                   help="measured shear band in place of --delta-over-H: a `granseg velocity` profile, or a "
                        "`granseg velocity-law` law (then give --M-g)")
    p.add_argument("--velocity-shape", choices=("exponential", "tabulated"), default="exponential",
                   help="with a measured profile: its exponential fit (default) or its own shear rate -dv/dz")
    p.add_argument("--M-g", dest="M_g", type=float, help="grain mass, kg (for a velocity law's M~ = M_w / M_g)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="any other model parameter, e.g. --set b=0.05 (repeatable)")
    p.add_argument("--t-end", type=float, default=3600.0, help="end time, s (default 3600)")
    p.add_argument("--dt", type=float, default=2.0, help="output interval, s (default 2)")
    p.add_argument("--n-cells", type=int, default=180, help="finite-volume cells (default 180)")
    p.add_argument("--rtol", type=float, help="relative tolerance of the stepper")
    p.add_argument("--atol", type=float, help="absolute tolerance of the stepper")
    p.add_argument("--out", default="granseg-simulation",
                   help="figure path without extension; writes OUT.png and OUT.pdf")
    p.add_argument("--npz", help="also write the model map (15 layers, or the --like map's) as a map .npz (docs/formats.md)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def _density(name: str | None, value: float | None, which: str) -> float:
    from granseg.model import MATERIALS

    if value is not None:
        return value
    lookup = {k.lower(): v for k, v in MATERIALS.items()}
    if name is None or name.lower() not in lookup:
        raise ValueError(f"--{which}: unknown material {name!r}; known: {', '.join(MATERIALS)}")
    return lookup[name.lower()]


def _extra(pairs: list[str]) -> dict[str, float]:
    out = {}
    for item in pairs:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item!r}: expected NAME=VALUE")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--set {item!r}: {value!r} is not a number") from None
    return out


def _measured(args: argparse.Namespace, params: dict[str, float]) -> dict[str, float]:
    """delta/H (and v1) from a ``--velocity`` file; a law needs the bed's M~ = M_w / M_g."""
    from granseg.model import defaults
    from granseg.velocity import ShearBandLaw, load_velocity, measured_params

    if args.delta_over_H is not None:
        raise ValueError("--velocity and --delta-over-H: give one (the velocity file measures delta/H)")
    v = load_velocity(args.velocity)
    if isinstance(v, ShearBandLaw) and not (args.M_g and args.M_g > 0):
        raise ValueError("--velocity: a shear-band law needs the bed's grain mass --M-g (kg) > 0")
    m_tilde = params.get("M_w", defaults()["M_w"]) / args.M_g if args.M_g else float("nan")
    return measured_params(v, [m_tilde], shape=args.velocity_shape, cells=[params])[0]


def run(args: argparse.Namespace) -> int:
    import granseg
    from granseg import fit, plot
    from granseg.plot.base import literal

    like = _like(args)
    if like is not None:
        params = like.case()
        args.heavy, args.light = like.heavy, like.light
    else:
        params = {"rho_h": _density(args.heavy, args.rho_h, "heavy"),
                  "rho_l": _density(args.light, args.rho_l, "light"), "c0": args.c0}
    for key in ("k", "delta_over_H"):
        if getattr(args, key) is not None:
            params[key] = getattr(args, key)
    params.update(_extra(args.set))
    if args.velocity:
        params.update(_measured(args, params))
    if not (args.t_end > 0 and args.dt > 0):
        raise ValueError("--t-end and --dt must be > 0 s")
    if like is None:
        from granseg.model import MAX_OUTPUT_TIMES

        n_out = np.floor(args.t_end / args.dt) + 1  # counted before the array is built
        if not np.isfinite(n_out) or n_out > MAX_OUTPUT_TIMES:
            raise ValueError(f"--t-end {args.t_end:g} s / --dt {args.dt:g} s asks for {n_out:.3g} output times; "
                             f"at most {MAX_OUTPUT_TIMES} per run (raise --dt)")
    t = like.t if like is not None else np.arange(0.0, args.t_end + 0.5 * args.dt, args.dt)
    stem = Path(args.out)
    outputs = [stem.with_name(stem.name + ext) for ext in (".png", ".pdf")]
    for p in outputs + ([Path(args.npz)] if args.npz else []):
        granseg._io.check_writable(p, args.force)

    start = time.perf_counter()
    sol = granseg.simulate(t=t, n_cells=args.n_cells, rtol=args.rtol, atol=args.atol, field=True, **params)
    elapsed = time.perf_counter() - start
    steady = granseg.steady_state(n_cells=args.n_cells, **params)
    layers = sol.layers(like.n_layers if like is not None else 15)
    bottom = fit.fit_tanh(sol.t, layers[:, 0])
    _summary(args, sol, layers, steady, bottom, elapsed)
    if like is not None:
        from granseg.maps import moving_average

        diff = moving_average(layers, like.smoothing_frames) - like.c
        print(f"  against {args.like} ({like.name}, {like.n_layers} layers, view {like.view or 'wall'}): "
              f"RMSD {np.sqrt(np.nanmean(diff**2)):.4f}")

    p = sol.params
    title = (f"{literal(args.heavy) if args.rho_h is None else ''}/{literal(args.light) if args.rho_l is None else ''} "
             rf"$\delta_R$ = {p['rho_h'] / p['rho_l']:.2f}, $c_0$ = {p['c0']:.2f}, "
             rf"k = {p['k']:.2f}, $\delta/H$ = {p['delta_over_H']:.3f}").lstrip("/ ")
    fig = plot.simulation(sol, steady=steady, fit=bottom if bottom.converged else None, title=title)
    written = plot.save_figure(fig, stem, force=args.force)
    if args.npz:
        _write_npz(args, sol, layers, like.cell if like is not None else {})
        written.append(Path(args.npz))
    print("wrote " + ", ".join(str(w) for w in written))
    return 0


def _like(args: argparse.Namespace):
    """The map ``--like`` names (None without it); its experiment replaces the material options."""
    if not args.like:
        return None
    from granseg.maps import load_map

    if args.rho_h is not None or args.rho_l is not None:
        raise ValueError("--like and --rho-h/--rho-l: give one (the map names its densities)")
    return load_map(args.like)


def _summary(args, sol, layers, steady, bottom, elapsed) -> None:
    p, s = sol.params, sol.stats
    drift = np.max(np.abs(sol.depth_mean - sol.depth_mean[0])) / sol.depth_mean[0]
    print(f"granseg simulate: delta_R = {p['rho_h'] / p['rho_l']:.3f}, c0 = {p['c0']:.3f}, "
          f"k = {p['k']:.3f}, delta/H = {p['delta_over_H']:.3f}")
    print(f"  solved {sol.t.size} output times x {sol.z.size} cells in {elapsed * 1e3:.1f} ms "
          f"({s['steps']} steps, {s['rejected']} rejected, {s['rhs_evals']} flux evaluations)")
    print(f"  mass drift {drift:.1e} (relative), c in [{sol.c.min():.3g}, {sol.c.max():.3g}]")
    if bottom.converged:
        b = bottom.params
        print(f"  bottom layer: A = {b['A']:.3f}, t0 = {b['t0']:.0f} s, tau = {b['tau']:.0f} s (tanh fit)")
    z, c = steady
    print(f"  steady state (direct solve): bottom c = {c[0]:.3f}, top c = {c[-1]:.3f}; "
          f"run at t = {sol.t[-1]:.0f} s: bottom {sol.c[-1, 0]:.3f}, top {sol.c[-1, -1]:.3f}")
    picks = np.unique(np.searchsorted(sol.t, np.array([0.0, 0.1, 0.3, 1.0]) * sol.t[-1]).clip(0, sol.t.size - 1))
    print("  layer means, top layer first:   " + "  ".join(f"t={sol.t[i]:>6.0f}s" for i in picks))
    for j in range(layers.shape[1] - 1, -1, -1):
        print(f"    layer {j:2d}                      " + "  ".join(f"{layers[i, j]:>8.3f}" for i in picks))


def _write_npz(args, sol, layers, cell) -> None:
    from granseg.maps import save_map
    from granseg.model import derived

    p = sol.params
    n = layers.shape[1]
    area = derived(**p)["A"]  # annulus area, m^2, from the core
    rho_solid = p["rho_h"] * p["c0"] + p["rho_l"] * (1 - p["c0"])
    save_map(args.npz, c=layers, t=sol.t, z=(np.arange(n) + 0.5) * p["H"] / n,
             name="simulation", heavy=args.heavy, light=args.light, rho_h=p["rho_h"],
             rho_l=p["rho_l"], c0=p["c0"], M_g=p["phi_s"] * area * p["H"] * rho_solid,
             M_w=p["M_w"], force=args.force, **cell)
