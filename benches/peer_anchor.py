"""Peer anchor (issue 15): the G-PP run of compare_scipy.py solved with two peer PDE packages,
FiPy and py-pde, beside the scipy method of lines and granseg, all in one process.

    pip install -e '.[peer]'     # or: pip install 'fipy>=4.0,<5' 'py-pde>=0.59,<1'
    python benches/peer_anchor.py [--repeats 3] [--peers fipy,py-pde] [--check] [--out benches/results/peer.md]

The case is the one of compare_scipy.py and work_precision.py: glass/PP (rho_h 2450, rho_l 946),
c0 = 0.5, 3600 s, outputs every 2 s (1801 outputs), 180 cells. The reference is granseg at 1440
cells, rtol 1e-8; a setting's error is the largest error of its 15-layer map over all outputs.

Both peers solve exactly the equations of tests/reference_mol.py (central face fluxes
F = -w c - D dc/dz, face pressure from the cells above, point values of the quintic step, no flux
through either wall), with its constants, shear rate and diffusivity (``Reference.gdot``,
``Reference.diff``), initial state and layer means; ``check_port`` verifies, before anything is
timed, that each peer's operator equals ``Reference.rhs`` to round-off. The 180-cell central
scheme itself is 2.3e-4 from the refined solution, so that is the floor of every peer row.

* FiPy: ``TransientTerm == DiffusionTerm(D) - CentralDifferenceConvectionTerm(u)`` on a Grid1D,
  u = -w the (downward) segregation velocity, both coefficients zero on the two wall faces (no
  flux), LU solves. FiPy steps with backward Euler only; the time scheme here is BDF2 written in
  FiPy terms (``TransientTerm(coeff=a0)`` plus a source carrying the older level), variable step:
  backward Euler from 2 ms, doubling to h_start inside the first output interval, then doubling
  once per output interval up to dt (a plain fixed dt misses 1e-3 at dt 1 s: the error is in
  the first outputs, where the interface first smooths). The nonlinear coefficients (w depends on
  c and on the pressure) are evaluated at the extrapolated state for the first sweep and at the
  latest iterate for further sweeps. Setting: dt, h_start, sweeps per step.
* py-pde: a ``PDEBase`` subclass on a 1-D ``CartesianGrid`` whose evolution rate is the same
  conservative stencil (numpy, and compiled with numba for the solvers), solved by py-pde's own
  steppers (explicit Euler, adaptive Runge-Kutta 5(4)) and by its ``scipy`` solver (solve_ivp
  BDF with the banded sparsity, restarted by py-pde at every output interrupt). py-pde's
  ``implicit`` and ``crank-nicolson`` solvers iterate to a fixed point, which converges only for
  steps below the explicit stability limit here, so they gain nothing and are left out.

For each setting of each ladder: best-of-N wall time of the run and its 15 layers, and the layer
error; the fastest setting meeting 1e-3 is the peer's figure. granseg (rtol 3e-4, atol 3e-5,
best of 15) and the scipy reference (reference_mol at rtol 1e-3, atol 3e-6) are timed in the same
process, and the ratios are against them. ``--check`` also solves reference_mol at rtol 1e-8 (about
70 s) and reports how far each peer's tightest setting is from it: the port against the port.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from compare_scipy import GPP, TARGET, T, best_time  # noqa: E402  (the case and the timer, one definition)

import granseg  # noqa: E402
from reference_mol import DP, I0, MU_2, MU_MIN, P_LOAD, PHI, G, H, Reference  # noqa: E402

N_CELLS = 180



# ---------------------------------------------------------------- the model, as reference_mol has it

def segregation_velocity(mol: Reference, c: np.ndarray) -> np.ndarray:
    """w (positive downward) at the n - 1 interior faces, as ``Reference.rhs`` has it."""
    return mol.segregation_velocity(c)


def make_numba_rhs(mol: Reference):
    """``Reference.rhs`` as one compiled loop over the faces, lid to plate (for py-pde's solvers)."""
    import numba

    n, dz, rho_h, rho_l, k = mol.n, mol.dz, mol.rho_h, mol.rho_l, mol.k
    gdot, diff = mol.gdot.copy(), mol.diff.copy()

    @numba.njit
    def rhs(c, t):
        out = np.empty(n)
        above = 0.0  # sum of rho over the cells above the face
        flux_above = 0.0  # flux through the face above the cell (the lid's is zero)
        for i in range(n - 2, -1, -1):  # face i + 1/2, between cells i and i + 1
            above += rho_h * c[i + 1] + rho_l * (1 - c[i + 1])
            p = P_LOAD + G * PHI * dz * above
            cf = 0.5 * (c[i] + c[i + 1])
            rf = rho_h * cf + rho_l * (1 - cf)
            inertial = gdot[i] * DP * np.sqrt(rf * PHI / p)
            mu = MU_MIN + (MU_2 - MU_MIN) / (I0 / inertial + 1)
            w = DP**2 * G * (rho_h - rho_l) * (1 - cf) * gdot[i] / (18 * k * mu * p)
            flux = -w * cf - diff[i] * (c[i + 1] - c[i]) / dz
            out[i + 1] = -(flux_above - flux) / dz
            flux_above = flux
        out[0] = -flux_above / dz  # the plate's face carries no flux
        return out

    return rhs


# ---------------------------------------------------------------- FiPy

class FipyPeer:
    """BDF2 in FiPy terms on a Grid1D; settings (dt, h_start, sweeps)."""

    name = "FiPy"

    def __init__(self, mol: Reference):
        import fipy

        self.fipy, self.mol = fipy, mol

    def label(self, s) -> str:
        dt, h_start, sweeps = s
        return (f"BDF2, dt {dt:g} s (from {h_start:g} s, doubling per output), "
                f"{sweeps} sweep{'s' if sweeps > 1 else ''}/step")

    def build(self):
        f, mol = self.fipy, self.mol
        mesh = f.Grid1D(nx=mol.n, dx=mol.dz)
        c = f.CellVariable(mesh=mesh, value=mol.initial(), hasOld=True)
        diff = f.FaceVariable(mesh=mesh, value=np.r_[0.0, mol.diff, 0.0])  # zero on the walls: no flux
        u = f.FaceVariable(mesh=mesh, rank=1, value=0.0)
        a0 = f.CellVariable(mesh=mesh, value=1.0)
        older = f.CellVariable(mesh=mesh, value=0.0)
        eq = (f.TransientTerm(coeff=a0)
              == f.DiffusionTerm(coeff=diff) - f.CentralDifferenceConvectionTerm(coeff=u) + older)
        return c, u, a0, older, eq

    def operator_residual(self, c_values: np.ndarray) -> np.ndarray:
        """FiPy's discrete right-hand side (per unit volume) at the state c, for check_port."""
        f, mol = self.fipy, self.mol
        mesh = f.Grid1D(nx=mol.n, dx=mol.dz)
        c = f.CellVariable(mesh=mesh, value=c_values)
        diff = f.FaceVariable(mesh=mesh, value=np.r_[0.0, mol.diff, 0.0])
        u = f.FaceVariable(mesh=mesh, rank=1, value=np.r_[0.0, -segregation_velocity(mol, c_values), 0.0][None])
        term = f.DiffusionTerm(coeff=diff) - f.CentralDifferenceConvectionTerm(coeff=u)
        return np.asarray(term.justResidualVector(var=c)) / mol.dz

    def run(self, s) -> np.ndarray:
        dt, h_start, sweeps = s
        mol = self.mol
        c, u, a0, older, eq = self.build()
        # FiPy's default criterion scales the tolerance by |b|, and its LU solver checks the
        # residual *before* solving: late in the run, when a step changes c by little, the old
        # state already passes and the solve is skipped (a 5e-3 layer error). "initial" always
        # solves at least once.
        solver = self.fipy.LinearLUSolver(criterion="initial", tolerance=1e-10)
        interval = T[1] - T[0]
        # step ratios <= 2 keep variable-step BDF2 zero-stable: the first interval starts with
        # h0, h0, 2 h0, ... up to h_start; each later interval doubles the step, up to dt
        h0 = 2.0**-9
        n_ramp = int(round(np.log2(h_start / h0)))
        self.n_steps = 0
        out = np.empty((len(T), mol.n))
        out[0] = mol.initial()
        cn = out[0].copy()
        cprev, hprev = None, None
        for i in range(1, len(T)):
            h_i = min(dt, h_start * 2.0 ** min(i - 1, 60))
            per = int(round(interval / h_i))
            assert abs(per * h_i - interval) < 1e-12, "steps must divide the output interval"
            # the ramp h0, h0, 2 h0, ..., h_start / 2 adds up to one step h_start
            steps = [h0] + [h0 * 2**j for j in range(n_ramp)] + [h_i] * (per - 1) if i == 1 else [h_i] * per
            for h in steps:
                self.n_steps += 1
                c.updateOld()
                if cprev is None:  # backward Euler
                    a0.setValue(1.0)
                    older.setValue(0.0)
                    guess = cn
                else:  # variable-step BDF2: a0 (c - c^n) / h = L(c) + a2 (c^n - c^(n-1)) / h
                    r = h / hprev
                    a0.setValue((1 + 2 * r) / (1 + r))
                    older.setValue(r * r / (1 + r) * (cn - cprev) / h)
                    guess = cn + r * (cn - cprev)
                for sweep in range(sweeps):
                    state = guess if sweep == 0 else np.asarray(c.value)
                    u.setValue(np.r_[0.0, -segregation_velocity(mol, state), 0.0][None])
                    eq.sweep(var=c, dt=h, solver=solver)
                cprev, hprev = cn, h
                cn = np.array(c.value)
            out[i] = cn
        return out

    def stats(self) -> str:
        return f"{self.n_steps} steps"


# ---------------------------------------------------------------- py-pde

class PyPdePeer:
    """py-pde's solvers on the same stencil; settings (solver, keyword arguments)."""

    name = "py-pde"

    def __init__(self, mol: Reference):
        import pde

        self.pde, self.mol = pde, mol
        numba_rhs = make_numba_rhs(mol)

        class Segregation(pde.PDEBase):
            """dc/dt = d/dz (w c) + d/dz (D dc/dz), no flux through the plate and the lid."""

            def evolution_rate(self, state, t=0):
                return pde.ScalarField(state.grid, mol.rhs(t, state.data))

            def make_evolution_rate(self, state, backend):
                if backend.name == "numba":
                    return numba_rhs
                return lambda data, t: mol.rhs(t, data)

        self.eq = Segregation()
        self.numba_rhs = numba_rhs
        self.grid = pde.CartesianGrid([[0.0, H]], [mol.n], periodic=False)
        assert np.allclose(self.grid.axes_coords[0], mol.z)

    @staticmethod
    def label(s) -> str:
        solver, kw = s
        if solver == "euler":
            return f"explicit Euler, dt {kw['dt']:g} s"
        if solver == "runge-kutta":
            return f"adaptive Runge-Kutta 5(4), tolerance {kw['tolerance']:g}"
        return f"`scipy` solver: solve_ivp {kw['method']}, banded sparsity, rtol {kw['rtol']:g}, atol {kw['atol']:g}"

    def run(self, s) -> np.ndarray:
        solver, kw = s
        storage = self.pde.MemoryStorage()
        state = self.pde.ScalarField(self.grid, self.mol.initial())
        kw = dict(kw)
        if solver == "scipy":
            kw["jac_sparsity"] = self.mol.sparsity()
        self.info = self.eq.solve(state, t_range=float(T[-1]), tracker=[storage.tracker(float(T[1] - T[0]))],
                                  solver=solver, backend="numba", ret_info=True, **kw)[1]
        data = np.array(storage.data)
        assert data.shape == (len(T), self.mol.n), data.shape
        return data

    def stats(self) -> str:
        s = self.info["solver"]
        if self.info["solver"]["class"] == "ScipySolver":
            return f"{s.get('steps', '?')} solve_ivp steps"
        if "dt_statistics" in s:
            return f"{int(s['dt_statistics']['count'])} steps"
        return f"{s.get('steps', '?')} steps"


# ---------------------------------------------------------------- checks and ladders

LADDERS = {
    "FiPy": [(2.0, 0.25, 1), (2.0, 2.0**-4, 1), (2.0, 2.0**-4, 2), (1.0, 2.0**-5, 1)],
    "py-pde": [("euler", dict(dt=5e-3)), ("runge-kutta", dict(adaptive=True, tolerance=1e-3)),
               ("scipy", dict(method="BDF", rtol=1e-3, atol=3e-6)),
               ("scipy", dict(method="BDF", rtol=1e-4, atol=1e-7))],
}
TIGHT = {"FiPy": (0.5, 2.0**-7, 1), "py-pde": ("runge-kutta", dict(adaptive=True, tolerance=1e-6))}


def check_port(mol: Reference, peers: dict) -> list[str]:
    """Each peer's discrete operator against Reference.rhs on random states in [0, 1]."""
    lines = []
    rng = np.random.default_rng(15)
    states = [rng.random(mol.n) for _ in range(3)] + [mol.initial()]
    scale = max(np.abs(mol.rhs(0, c)).max() for c in states)
    w_err = 0.0
    for c in states:
        flux = np.r_[0.0, -segregation_velocity(mol, c) * 0.5 * (c[1:] + c[:-1])
                     - mol.diff * np.diff(c) / mol.dz, 0.0]
        w_err = max(w_err, np.abs(-np.diff(flux) / mol.dz - mol.rhs(0, c)).max())
    checks = {"segregation_velocity (numpy, shared by FiPy)": w_err}
    if "FiPy" in peers:
        checks["FiPy DiffusionTerm - CentralDifferenceConvectionTerm"] = max(
            np.abs(peers["FiPy"].operator_residual(c) - mol.rhs(0, c)).max() for c in states)
    if "py-pde" in peers:
        checks["py-pde evolution rate (numba)"] = max(
            np.abs(peers["py-pde"].numba_rhs(c, 0.0) - mol.rhs(0, c)).max() for c in states)
    for name, err in checks.items():
        rel = err / scale
        lines.append(f"{name}: largest difference from Reference.rhs {rel:.1e} (relative)")
        if rel > 1e-10:
            raise AssertionError(lines[-1])
    return lines


def measure(repeats: int, peer_names: list[str], check: bool) -> dict:
    mol = Reference(GPP["rho_h"], GPP["rho_l"], GPP["c0"], n=N_CELLS)
    peers = {}
    if "fipy" in peer_names:
        peers["FiPy"] = FipyPeer(mol)
    if "py-pde" in peer_names:
        peers["py-pde"] = PyPdePeer(mol)
    port = check_port(mol, peers)
    for line in port:
        print(line, flush=True)
    ref = granseg.simulate(**GPP, t=T, n_cells=1440, rtol=1e-8, atol=1e-10).layers()
    mol_tight = mol.layers(mol.solve(T, 1e-8, 1e-10)) if check else None
    res: dict = dict(port=port, peers={}, tight={})
    for name, peer in peers.items():
        rows = []
        for s in LADDERS[name]:
            t0 = time.perf_counter()
            layers = mol.layers(peer.run(s))  # untimed first run: numba compiles here
            first = time.perf_counter() - t0
            err = np.abs(layers - ref).max()
            stats = peer.stats() if hasattr(peer, "stats") else ""
            if name == "FiPy":  # nothing to compile: the first run counts
                wall = min(first, best_time(lambda s=s, p=peer: mol.layers(p.run(s)), max(0, repeats - 1)))
            else:  # the first run compiled py-pde's stepper with numba
                wall = best_time(lambda s=s, p=peer: mol.layers(p.run(s)), repeats)
            rows.append((peer.label(s), wall, err, stats))
            print(f"{name} {peer.label(s)}: {wall:.3f} s, error {err:.2e} {stats}", flush=True)
        res["peers"][name] = rows
        s = TIGHT[name]
        t0 = time.perf_counter()
        layers = mol.layers(peer.run(s))
        wall = time.perf_counter() - t0
        res["tight"][name] = (peer.label(s), wall, np.abs(layers - ref).max(),
                              None if mol_tight is None else np.abs(layers - mol_tight).max())
        print(f"{name} tight {peer.label(s)}: {res['tight'][name]}", flush=True)
    # the two anchors, measured in the same process
    ours = lambda: granseg.simulate(**GPP, t=T, rtol=3e-4, atol=3e-5).layers()  # noqa: E731
    res["granseg"] = (best_time(ours, 15), np.abs(ours() - ref).max())
    sp = lambda: mol.layers(mol.solve(T, 1e-3, 3e-6))  # noqa: E731
    res["scipy"] = (best_time(sp, max(3, repeats)), np.abs(sp() - ref).max())
    res["scipy_tight"] = None if mol_tight is None else np.abs(mol_tight - ref).max()
    print(f"granseg {res['granseg']}, scipy {res['scipy']}", flush=True)
    return res


def fmt_time(s: float) -> str:
    return f"{s * 1e3:.2f} ms" if s < 0.1 else f"{s:.2f} s"


def report(res: dict, command: str, repeats: int) -> str:
    import fipy
    import pde

    t_g, e_g = res["granseg"]
    t_s, e_s = res["scipy"]
    versions = {"FiPy": fipy.__version__, "py-pde": pde.__version__}
    lines = ["    " + command, "",
             "G-PP (rho_h 2450, rho_l 946, c0 0.5), 3600 s, 1801 outputs, 180 cells; layer error = largest "
             "error of the 15-layer map against granseg at 1440 cells, rtol 1e-8. Wall time: the run and "
             f"its 15 layers, best of {repeats} for the peers (py-pde: after an untimed run that compiles with numba), "
             "one process.",
             "", "| peer | setting | wall time | layer error | meets 1e-3 |", "|---|---|---|---|---|"]
    fastest = {}
    for name, rows in res["peers"].items():
        for label, wall, err, stats in rows:
            ok = err <= TARGET
            note = f" ({stats})" if stats else ""
            lines.append(f"| {name} {versions[name]} | {label} | {fmt_time(wall)}{note} | {err:.1e} | "
                         f"{'yes' if ok else 'no'} |")
            if ok and (name not in fastest or wall < fastest[name][1]):
                fastest[name] = (label, wall, err)
    lines += ["", "| solver | setting | wall time | layer error | time / scipy | time / granseg |",
              "|---|---|---|---|---|---|",
              f"| granseg (ESDIRK3, Rust), best of 15 | rtol 3e-4, atol 3e-5 | {fmt_time(t_g)} | {e_g:.1e} "
              f"| {t_g / t_s:.3f} | 1 |",
              f"| scipy reference (tests/reference_mol.py, solve_ivp BDF) | rtol 1e-3, atol 3e-6 | {fmt_time(t_s)} "
              f"| {e_s:.1e} | 1 | {t_s / t_g:.0f} |"]
    for name, (label, wall, err) in fastest.items():
        lines.append(f"| **{name}** {versions[name]}, fastest setting meeting 1e-3 | {label} | {fmt_time(wall)} "
                     f"| {err:.1e} | {wall / t_s:.1f} | {wall / t_g:.0f} |")
    lines += ["", "Faithfulness of the ports to tests/reference_mol.py's equations:", ""]
    lines += [f"- {line}" for line in res["port"]]
    for name, (label, wall, err, err_mol) in res["tight"].items():
        extra = "" if err_mol is None else (f"; against reference_mol itself at rtol 1e-8 (same equations, "
                                            f"same 180 cells): {err_mol:.1e}")
        lines.append(f"- {name} at a tight setting ({label}, {fmt_time(wall)}): layer error {err:.1e}{extra}")
    if res["scipy_tight"] is not None:
        lines.append(f"- reference_mol at rtol 1e-8, atol 1e-10: layer error {res['scipy_tight']:.1e} (the "
                     "spatial error of the 180-cell central scheme, the floor of every row above)")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="best of N for the peers and scipy (granseg: 15)")
    ap.add_argument("--peers", default="fipy,py-pde", help="comma-separated: fipy, py-pde")
    ap.add_argument("--check", action="store_true", help="also compare with reference_mol at rtol 1e-8 (~70 s)")
    ap.add_argument("--out", type=Path, help="also write the markdown here (atomic, overwrites)")
    args = ap.parse_args()
    peer_names = [p.strip().lower() for p in args.peers.split(",") if p.strip()]
    unknown = set(peer_names) - {"fipy", "py-pde"}
    if unknown:
        ap.error(f"unknown peer(s): {', '.join(sorted(unknown))}")
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    res = measure(args.repeats, peer_names, args.check)
    text = report(res, "python benches/peer_anchor.py " + " ".join(sys.argv[1:]), args.repeats)
    print(text)
    if args.out:
        from granseg._io import atomic_write

        atomic_write(args.out, lambda p: p.write_text(text), force=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
