"""Figures render headless and are non-trivial; the report is opened as a user sees it."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import matplotlib.image as mpimg
import numpy as np
import pytest

from granseg import plot
from granseg._io import OutputExistsError
from granseg.fit import fit_campaign, tanh_curve
from granseg.maps import Map

H = 0.09
Z = (np.arange(15) + 0.5) * 6e-3


def fake_map(name: str, rho_h: float, seed: int, c0: float = 0.5, heavy: str = "h") -> Map:
    """A segregating map with noise; shape and values like a real experiment."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 1200.0, 4.0)
    dR = rho_h / 946.0
    A = 1 - 0.5 / dR**2.3
    tau = 1500.0 * np.exp(-0.8 * (dR - 1))
    f = tanh_curve(t, A, 0.6 * tau, tau)[:, None] * np.exp(-Z / 0.03)[None, :]
    start = (Z > (1 - c0) * H).astype(float)[None, :]
    c = np.clip(start * (1 - f) + f + rng.normal(0, 0.04, (t.size, 15)), 0, 1)
    return Map(c=c, t=t, z=Z, name=name, heavy=heavy, light="PP", rho_h=rho_h, rho_l=946.0,
               c0=c0, M_g=2.0, M_w=1.093)


@pytest.fixture(scope="module")
def maps() -> list[Map]:
    return [fake_map(n, r, i) for i, (n, r) in
            enumerate([("C-PP-50", 3500), ("G-PP-50", 2450), ("POM-PP-50", 1750), ("G-PP-75", 2450)])]


def assert_nontrivial(paths, min_colours: int = 50) -> None:
    png, pdf = paths
    assert png.suffix == ".png" and pdf.suffix == ".pdf"
    img = mpimg.imread(png)
    assert img.shape[0] > 300 and img.shape[1] > 500
    rgb = (img[..., :3] * 255).astype(np.uint8).reshape(-1, 3)
    assert np.unique(rgb, axis=0).shape[0] >= min_colours, "figure looks blank"
    assert rgb.std() > 10
    head = pdf.read_bytes()
    assert head.startswith(b"%PDF") and len(head) > 5000


def test_map_comparison(tmp_path, maps):
    m = maps[0]
    model = np.clip(m.c + 0.1, 0, 1)
    fig = plot.map_comparison(m, model, H=H, rmsd=0.1, initial=(np.linspace(0, H, 100), np.zeros(100)))
    axes = fig.get_axes()
    assert axes[1].get_xlabel() == plot.T_LABEL and axes[0].get_ylabel() == plot.H_LABEL
    assert len(axes) == 6  # profile, measured, model, residual + two colour bars
    assert_nontrivial(plot.save_figure(fig, tmp_path / "map"), min_colours=200)
    with pytest.raises(ValueError, match="model map shape"):
        plot.map_comparison(m, model[:, :3], H=H)


def test_curves_laws_grid_profiles(tmp_path, maps):
    fits = fit_campaign(maps)
    assert fits.beta is not None
    assert_nontrivial(plot.save_figure(plot.bottom_fits(maps, fits.tanh), tmp_path / "bottom"))
    assert_nontrivial(plot.save_figure(plot.laws(fits), tmp_path / "laws"))
    pts = [{"k": k, "delta_over_H": d} for k in (0.5, 0.6, 0.7) for d in (0.18, 0.2, 0.22)]
    r = [abs(p["k"] - 0.62) + abs(p["delta_over_H"] - 0.195) for p in pts]
    fig = plot.rmsd_grid(pts, r, best={"k": 0.62, "delta_over_H": 0.195},
                         stderr={"k": 0.01, "delta_over_H": 0.002})
    texts = [t.get_text() for t in fig.get_axes()[0].texts]
    assert len(texts) == 9 and f"{min(r):.3f}" in texts
    assert_nontrivial(plot.save_figure(fig, tmp_path / "grid"))
    params = {"H": H, "rpm": 23.44, "D_out": 0.19, "v1": 0.0, "delta_over_H": 0.195}
    fig = plot.profiles(params, deltas=[0.18, 0.2, 0.22], delta_err=0.004)
    (line,) = [ln for ln in fig.get_axes()[0].get_lines() if ln.get_label().startswith("calibrated")]
    v = line.get_xdata()
    assert v.max() == pytest.approx(23.44 * 2 * np.pi / 60 * 0.095, rel=1e-6)  # v0 at the bottom
    assert_nontrivial(plot.save_figure(fig, tmp_path / "profiles"))


def test_the_figures_load_without_the_frame_pipeline():
    # scikit-learn and the rest of granseg.measure took 1.5 s to import, which every command
    # that draws a figure paid for one check of the views' figure (BENCHMARKS "Ctrl-C at any moment")
    code = "import sys, granseg.plot; print(sorted(m for m in sys.modules if m.startswith(('sklearn', 'granseg.measure'))))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[]", r.stdout


def test_rmsd_grid_needs_two_parameters():
    with pytest.raises(ValueError, match="exactly two parameters"):
        plot.rmsd_grid([{"k": 0.5}, {"k": 0.6}], [0.1, 0.2])


def test_save_figure_never_overwrites(tmp_path, maps):
    fig = plot.bottom_fits(maps, {})
    plot.save_figure(fig, tmp_path / "f")
    (tmp_path / "f.png").unlink()  # only the PDF is left: still refused, nothing half-written
    with pytest.raises(OutputExistsError):
        plot.save_figure(fig, tmp_path / "f")
    assert not (tmp_path / "f.png").exists()
    plot.save_figure(fig, tmp_path / "f", force=True)
    assert (tmp_path / "f.png").exists()


# --------------------------------------------------------------------------- report (needs the solver)


def browser() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    pytest.importorskip("granseg._core", reason="the Rust extension is not built (maturin develop)")
    from granseg.maps import save_map
    from granseg.report import build_report

    camp = tmp_path_factory.mktemp("campaign")
    for i, (name, rho_h) in enumerate([("C-PP-50", 3500.0), ("G-PP-50", 2450.0), ("POM-PP-50", 1750.0)]):
        m = fake_map(name, rho_h, 10 + i)
        save_map(camp / f"{name}.npz", **{k: v for k, v in m.to_arrays().items()})
    (camp / "campaign.json").write_text('{"synthetic": true}')  # what granseg.synth.virtual.campaign writes
    out = tmp_path_factory.mktemp("report")
    page = build_report(camp, out, n_cells=60, max_nfev=4, progress=False, force=True)
    return page


def test_report_files_and_json(report_dir):
    out = report_dir.parent
    data = json.loads((out / "report.json").read_text())
    cal = data["calibration"]
    assert set(cal["best"]) == {"k", "delta_over_H"} and len(cal["grid"]) == 9
    assert [x["name"] for x in data["experiments"]] == ["C-PP-50", "G-PP-50", "POM-PP-50"]
    page = report_dir.read_text()
    # every figure is embedded and has its files beside the page
    assert page.count('<img class="fig"') == len(data["figures"]) == 7
    for fig in data["figures"]:
        assert (out / fig["png"]).stat().st_size > 10_000 and (out / fig["pdf"]).exists()
    # numbers on the page come from the JSON
    assert f"{cal['rmsd_mean']:.4f}" in page
    for g in cal["grid"]:
        assert f"{g['rmsd_mean']:.3f}" in page
    with pytest.raises(OutputExistsError):
        from granseg.report import build_report

        build_report(data["campaign"], out)  # refused before any work is done
    # where the numbers come from, and that they are not measurements
    prov = data["provenance"]
    assert prov["synthetic"] and prov["input"] == data["campaign"] and prov["command"] is None
    assert "SYNTHETIC DATA" in page and "class='banner'" in page and "granseg " + prov["granseg_version"] in page
    assert "RMSE</th>" in page and ">MSE<" not in page


def test_report_in_headless_browser(report_dir, tmp_path):
    exe = browser()
    if exe is None:
        pytest.skip("no headless browser: chromium / chromium-browser not on PATH "
                    "(CI installs Debian's chromium package)")
    flags = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
             "--virtual-time-budget=10000", f"--user-data-dir={tmp_path / 'profile'}"]
    url = report_dir.resolve().as_uri()
    dom = subprocess.run([*flags, "--dump-dom", url], capture_output=True, text=True, timeout=120)
    loaded = re.search(r'data-figures-loaded="(\d+)/(\d+)"', dom.stdout)
    assert loaded, f"page did not finish loading: {dom.stderr[-2000:]}"
    assert loaded.group(1) == loaded.group(2) == "7", loaded.group(0)
    shot = tmp_path / "report.png"
    subprocess.run([*flags, f"--screenshot={shot}", "--window-size=1280,2400", url],
                   capture_output=True, timeout=120, check=True)
    img = mpimg.imread(shot)
    assert img.shape[:2] == (2400, 1280)
    assert np.unique((img[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0).shape[0] > 100


def test_one_output_guard(tmp_path):
    from granseg._io import prepare_output_dir

    out = prepare_output_dir(tmp_path / "rep", ["index.html", "figures"], folders=["figures"])
    assert (out / "figures").is_dir()  # made once all checks pass
    with pytest.raises(OutputExistsError, match="figures"):
        prepare_output_dir(out, ["index.html", "figures"])
    assert prepare_output_dir(out, ["index.html", "figures"], force=True) == out
    (tmp_path / "file").write_text("mine")
    with pytest.raises(NotADirectoryError):
        prepare_output_dir(tmp_path / "file", ["index.html"], force=True)
    with pytest.raises(FileNotFoundError):
        prepare_output_dir(tmp_path / "missing" / "rep", ["index.html"], force=True)
    assert not (tmp_path / "missing").exists()


def test_both_pages_share_the_html_pieces(report_dir):
    from granseg.report import diagnosis, html

    out = report_dir.parent
    png = next((out / "figures").glob("*.png"))
    figs = [{"id": "gain", "caption": "RMSD <per> experiment", "png": f"figures/{png.name}",
             "pdf": "figures/gain.pdf"}]
    cand = {"name": "spin_up_delay", "law": "t -> t - 12 s", "rmsd": 0.05, "rmsd_held_out": 0.06,
            "gain_held_out": 0.001}
    doc = {"cause": "none", "explained": False, "summary": "No cause beats the noise.", "noise_floor": 0.04,
           "noise": {"method": "counts"}, "decision": {"reason": "no gain beyond the threshold"},
           "baseline": {"params": {"k": 0.6, "delta_over_H": 0.2}, "rmsd_mean": 0.0512,
                        "rmsd_held_out_mean": 0.0534},
           "candidates": [cand]}
    pages = [report_dir.read_text(), diagnosis.render(doc, figs, out)]
    for text in pages:
        assert f"<style>{html.CSS}</style><script>{html.SCRIPT}</script>" in text
        assert text.startswith("<!DOCTYPE html>") and '<div class="scroll"><table>' in text
    assert pages[1].count('<img class="fig"') == 1 and 'href="figures/gain.pdf"' in pages[1]
    assert "RMSD &lt;per&gt; experiment" in pages[1] and "0.0512" in pages[1] and "+0.0010" in pages[1]


def test_value_and_error_take_the_errors_digits():
    from granseg.report.html import nums, pm, pm_text, tidy_pm, yesno

    assert pm_text(1.29e-06, 1.4) == "0.0 ± 1.4"  # a value far below its error reads as zero
    assert pm_text(0.187, 0.00089) == "0.18700 ± 0.00089"
    assert pm_text(944.0, 300.0) == "940 ± 300"
    assert pm_text(1.29e-06, 2e-08) == "(1.290 ± 0.020)e-06"
    assert pm_text(-1e-9, 0.5) == "0.00 ± 0.50"  # no "-0.00"
    assert pm_text(0.5, None) == "0.5" and pm_text(0.5, float("nan")) == "0.5"
    assert pm(0.775, 0.028) == "0.775 &plusmn; 0.028"
    assert tidy_pm("starts 1.29e-06 ± 1.4 s after; k = 0.734 ± 0.011.") == "starts 0.0 ± 1.4 s after; k = 0.734 ± 0.011."
    assert nums([0.13999999999999999, 0.26]) == "[0.14, 0.26]"
    assert (yesno(True), yesno(False)) == ("yes", "no")


def test_the_diagnosis_page_states_its_provenance_threshold_and_rivals(tmp_path):
    from granseg.report import diagnosis

    cands = [{"name": "load_dependent_shear_band", "law": "delta/H = 0.187 ± 0.00089 x M~", "rmsd": 0.12,
              "rmsd_held_out": 0.123, "gain_held_out": 0.04},
             {"name": "evolving_shear_band", "law": "t0 = 1.29e-06 ± 1.4 s", "rmsd": 0.146,
              "rmsd_held_out": 0.158, "gain_held_out": 0.0052},
             {"name": "spin_up_delay", "law": "-", "rmsd": 0.15, "rmsd_held_out": 0.164, "gain_held_out": -0.0003}]
    doc = {"cause": "load_dependent_shear_band", "explained": True, "summary": "s.", "noise_floor": 0.121,
           "noise": {"method": "counts"},
           "decision": {"reason": "r", "gain_threshold": 0.02, "excess_threshold": 1.06, "coherence_alpha": 1e-3,
                        "coherence_share": 0.35, "runner_up": "evolving_shear_band",
                        "best_candidate": "load_dependent_shear_band", "margin_to_runner_up": 0.0348},
           "baseline": {"params": {"k": 0.79, "delta_over_H": 0.19}, "rmsd_mean": 0.15, "rmsd_held_out_mean": 0.163},
           "candidates": cands,
           "provenance": {"input": "camp/", "granseg_version": "9.9", "created": "2026-01-02T03:04:05+00:00",
                          "command": "granseg diagnose camp/ --report r", "synthetic": True, "origin": "a test"}}
    page = diagnosis.render(doc, [], tmp_path)
    assert "SYNTHETIC DATA &mdash; a test" in page and "<code>granseg diagnose camp/ --report r</code>" in page
    assert "2026-01-02 03:04:05 UTC" in page and "granseg 9.9" in page
    assert "misfit explained: yes" in page and "True" not in page
    # the threshold in both units: 2.0 % of the held-out RMSD 0.163 is a gain of 0.0033
    assert "2.0 %" in page and "0.0033" in page and "+24.5" in page
    # the other candidate beyond the threshold and the runner-up's margin are on the page
    assert "besides the named cause" in page and "evolving shear band (+0.0052, +3.2 %)" in page
    assert "Runner-up: evolving shear band" in page and "0.0348" in page
    assert "0.0 ± 1.4" in page and "1.29e-06" not in page

