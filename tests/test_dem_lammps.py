"""The shipped LAMMPS example (examples/dem/) run for real and read back (issue 12).

Needs Debian's ``lammps`` package (``lmp`` with the GRANULAR pair styles; ``./dev.sh test``
installs it on CI machines); skipped where it is absent. The short run takes seconds; the
slow one (``-m slow``) shears the example's full bed long enough for a shear band."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from granseg.dem import load_run

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "dem"
LMP = shutil.which("lmp")
pytestmark = pytest.mark.skipif(LMP is None, reason="LAMMPS (lmp) is not installed: apt-get install lammps")


def _run(tmp_path: Path, **var: object) -> tuple[Path, dict[str, int]]:
    """Run the example with ``var`` overriding its variables; the run directory (dumps and
    the ``dem.json`` the script writes beside them) and the grain counts LAMMPS printed."""
    out = tmp_path / "run"
    args = [LMP, "-in", str(EXAMPLE / "shear_cell.in"), "-log", str(tmp_path / "log.lammps"), "-screen", "none",
            "-var", "out", str(out)]
    for k, v in var.items():
        args += ["-var", k, str(v)]
    subprocess.run(args, check=True, cwd=tmp_path, timeout=1800)
    log = (tmp_path / "log.lammps").read_text()
    m = re.search(r"granseg shear cell: (\d+) grains \((\d+) light, (\d+) heavy\)", log)
    assert m, "the example prints its grain counts"
    return out, dict(zip(("grains", "light", "heavy"), map(int, m.groups()), strict=True))


def _check_conserved(run, m, counts: dict[str, int]) -> None:
    """Every snapshot holds every grain once, and the bed's volume-mean heavy share is c0."""
    assert np.all(m.n.sum(1) == counts["grains"]) and np.all(m.n_heavy.sum(1) == counts["heavy"])
    vol = np.array([[np.sum(s.columns["radius"][(s.columns["type"] < 3)] ** 3)] for s in run.snapshots])
    tab = run._tables("bulk")
    np.testing.assert_allclose(tab["vol"].sum(1, keepdims=True), vol)
    np.testing.assert_allclose(tab["vol_heavy"].sum(1) / tab["vol"].sum(1), m.c0, rtol=1e-12)


def test_short_lammps_run_reads_back_whole_and_stratified(tmp_path):
    out, counts = _run(tmp_path, Lx=6, Ly=4, layers=5, settle_steps=20000, steps=4000, dump_every=1000,
                       ratio=3, load=200, U=0.5)
    run = load_run(out)  # the config the run wrote beside its dumps
    assert len(run.snapshots) == 5 and run.n_layers in (4, 5, 6)
    m = run.to_map("bulk")
    _check_conserved(run, m, counts)
    assert m.c[0, -1] > 0.8 and m.c[0, 0] < 0.2  # heavy on top at the start
    assert m.rho_h / m.rho_l == pytest.approx(3.0)
    assert m.M_w == pytest.approx(200 * 946 * 0.006**4 / 0.0247311**2 / run.config.g, rel=1e-9)
    assert run.config.plate_speed == pytest.approx(0.5 * 0.006 / 0.0247311)
    assert run.config.g == pytest.approx(9.81, rel=1e-4) and run.area == pytest.approx(24 * 0.006**2)
    w = run.to_map("wall")
    assert np.all(w.n <= m.n) and w.n.sum() > 0
    assert any("[3, 4]" in note for note in run.notes)  # plate and lid spheres are not grains


@pytest.mark.slow
def test_sheared_example_bed_has_a_shear_band_and_stays_whole(tmp_path):
    out, counts = _run(tmp_path, ratio=2, settle_steps=20000, steps=60000, dump_every=5000)
    run = load_run(out)
    m = run.to_map("bulk")
    _check_conserved(run, m, counts)
    prof = run.velocity_profile()
    v = prof.v
    assert v[0] > 0.5 * run.config.plate_speed and v[-1] < 0.2 * v[0]  # fast at the plate, slow at the lid
    assert np.all(np.diff(v[np.isfinite(v)]) < prof.v_err[1:] * 3 + 1e-3)  # falls with height
    assert prof.fit.converged and 0.03 < prof.delta_over_H < 0.6
