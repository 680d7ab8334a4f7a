"""Where the outward centre bias on the physically based fixtures comes from (issue 9).

On the Mitsuba looks (tests/fixtures/pbr) detected centres lie outward of the
truth, more the further from the image centre. This script separates the
candidate causes, each measured on its own:

(a) the truth's definition. The truth is the area centroid of each sphere's
    outline traced through the refracting wall (``pbr._Cell.outline``), not
    the image of its 3-D centre. Measured: projected centre and the centre
    of a circle fitted to the outline left visible by the sphere's
    neighbours (the curved wall packs them so that they overlap a little in
    the image), both against the truth, by position.
(b) the camera model. The renderer maps canvas -> sensor with
    ``cv2.undistortPoints`` (60 iterations), the pipeline sensor -> canvas
    with ``cv2.projectPoints``: the round trip at the window's corners.
(c) the detector. The detection error by position on the fixtures (what
    the pipeline's frame worker finds, matched to the truth within 0.3 D),
    the per-frame layer-count error with the detected x or y replaced by
    the truth (which of the two the count misses come from; also y replaced
    only where the true centre lies within ON_BOUNDARY of a layer boundary),
    the spheres counted in another layer than the truth's and how far their
    true centres lie from the boundary they crossed, the mean y
    and outward x error by height (two layers at a time), how much further
    apart lying pairs across the window's middle column are than pairs on
    one side (detected and true), and, with
    ``--render`` (needs mitsuba, about a minute on two cores), a control:
    the same packing rendered under the fixtures' two side panels, without
    vignetting, with the panels 600 and 1500 mm from the axis instead of 270,
    and under one panel behind the camera (shading symmetric about every view
    direction).

    PYTHONPATH=python python benches/bench_pbr_centre_bias.py [--looks steel-pom pom-pp ...] \
        [--render [--controls-only]] [--json benches/results/pbr_centre_bias.json] [--dir FOLDER]

``--dir`` reads the looks from another folder: the tuning family, other
packings of the same looks (``python -m granseg.synth.pbr fixtures FOLDER
--seed-offset 100``), which the detector may be developed on; the committed
fixtures are what it is judged on.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

import granseg.measure.pipeline as pipeline
from granseg._io import save_json
from granseg.measure.experiment import load_experiment
from granseg.measure.layers import height, in_window, layer_counts, layer_index
from granseg.measure.outline import TOUCHING
from granseg.synth.pbr import _Cell, load_fixture

PBR = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "pbr"
BAND = 40.0  # px from the window's sides / top and bottom that count as "near" them
FAR_PANELS_MM = (600.0, 1500.0)  # the fixtures' panels are 270 mm from the cell's axis
# A true centre this close to a layer boundary [D] (0.17 px at the fixtures' 34 px) is counted on
# either side by any error a detector can be expected to have: the renderer's packings stack some
# spheres in exact columns from a bump, whole diameters apart.
ON_BOUNDARY = 0.005


def _outward(rows: np.ndarray, win) -> dict:
    """Mean outward error [px]: x near the sides and in the middle, y near top/bottom and in the middle.

    rows: (n, 4) true x, y and error dx, dy."""
    x0, y0, x1, y1 = win
    xm, ym = (x0 + x1) / 2, (y0 + y1) / 2
    ox, oy = rows[:, 2] * np.sign(rows[:, 0] - xm), rows[:, 3] * np.sign(rows[:, 1] - ym)
    side = (rows[:, 0] < x0 + BAND) | (rows[:, 0] > x1 - BAND)
    top_bottom = (rows[:, 1] < y0 + BAND) | (rows[:, 1] > y1 - BAND)
    return {"x_sides": round(float(ox[side].mean()), 3),
            "x_middle": round(float(ox[np.abs(rows[:, 0] - xm) < BAND].mean()), 3),
            "y_top_bottom": round(float(oy[top_bottom].mean()), 3),
            "y_middle": round(float(oy[np.abs(rows[:, 1] - ym) < BAND].mean()), 3)}


def geometry(truth) -> dict:
    """(a): projected centre and the circle fitted to the visible (unoccluded) outline, against the truth."""
    e = truth.experiment
    d = float(e["particle_diameter_px"])
    cell = _Cell(np.asarray(e["camera_matrix"], float), d, truth.n.shape[1])
    proj_rows, vis_rows = [], []
    n_dir = 48
    phi = np.arange(n_dir) * 2 * np.pi / n_dir
    rad = np.linspace(0.25 * d, 0.65 * d, 321)
    for rows, cen in zip(truth.particles, truth.centres, strict=True):
        inside = np.flatnonzero(rows[:, 4] > 0)
        proj = cell.project(cen[inside, :3])
        proj_rows.append(np.column_stack([rows[inside, :2], proj - rows[inside, :2]]))
        for i in inside:
            uv, c3, r = rows[i, :2], cen[i, :3], cen[i, 3]
            o, dr = cell.rays(uv[0] + rad[None] * np.cos(phi)[:, None], uv[1] + rad[None] * np.sin(phi)[:, None])

            def hit(c, rr, o=o, dr=dr):
                rel = c - o
                along = np.sum(rel * dr, -1)
                gap2 = np.sum(rel * rel, -1) - along ** 2
                return np.where(gap2 < rr ** 2, along - np.sqrt(np.maximum(rr ** 2 - gap2, 0)), np.inf)

            t_own = hit(c3, r)
            seen = np.isfinite(t_own)
            for j in np.flatnonzero(np.linalg.norm(cen[:, :3] - c3, axis=1) < 2.2 * r + 1):
                if j != i:
                    seen &= ~(hit(cen[j, :3], cen[j, 3]) < t_own)
            edge = rad[np.argmax(~seen, axis=1)]
            ex, ey = uv[0] + edge * np.cos(phi), uv[1] + edge * np.sin(phi)
            sol = np.linalg.lstsq(np.column_stack([ex, ey, np.ones(n_dir)]), -(ex ** 2 + ey ** 2), rcond=None)[0]
            vis_rows.append([uv[0], uv[1], -sol[0] / 2 - uv[0], -sol[1] / 2 - uv[1]])
    win = e["window"]
    return {"projected_centre_minus_truth": _outward(np.concatenate(proj_rows), win),
            "visible_outline_circle_minus_truth": _outward(np.array(vis_rows), win)}


def camera_round_trip(truth) -> float:
    """(b): largest |undistortPoints(projectPoints(p)) - p| [px] at the window's corners and side midpoints."""
    e = truth.experiment
    k, dist = np.asarray(e["camera_matrix"], float), np.asarray(e["dist_coeffs"], float)
    x0, y0, x1, y1 = e["window"]
    pts = np.array([[x, y] for x in (x0, (x0 + x1) / 2, x1) for y in (y0, (y0 + y1) / 2, y1)])
    ray = np.column_stack([(pts - k[:2, 2]) / [k[0, 0], k[1, 1]], np.ones(len(pts))])
    sensor, _ = cv2.projectPoints(ray.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, dist)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)
    back = cv2.undistortPoints(sensor, k, dist, P=k, criteria=crit).reshape(-1, 2)
    return float(np.abs(back - pts).max())


def detections(folder: Path):
    """Every sphere the frame worker finds (also just outside the window's sides), per frame, and the truth."""
    truth = load_fixture(folder)
    exp = load_experiment(folder / "experiment.json")
    size = truth.images[0].shape[1::-1]
    keep = pipeline.in_window
    # keep the spheres up to 20 px beyond the sides, to see which ones the bias pushes out
    pipeline.in_window = lambda x, y, w: in_window(x, y, (w[0] - 20, w[1], w[2] + 20, w[3]))
    try:
        worker = pipeline._FrameWorker(exp, size)
        worker.learn(truth.images[0])
        found = [worker(str(i), img)[0] for i, img in enumerate(truth.images)]
    finally:
        pipeline.in_window = keep
    return truth, exp, found


def detector(folder: Path) -> dict:
    """(c): detection error by position and the layer-count error with detected x or y replaced by the truth."""
    truth, exp, found = detections(folder)
    d = exp.particle_diameter_px
    rows, counts = [], {k: [] for k in ("detected", "true_x", "true_y", "true_xy", "true_y_on_boundaries")}
    flips = []
    for tp, s in zip(truth.particles, found, strict=True):
        dist, j = cKDTree(tp[:, :2]).query(np.column_stack([s.x, s.y]))
        m = dist < 0.3 * d
        rows.append(np.column_stack([tp[j[m], :2], s.x[m] - tp[j[m], 0], s.y[m] - tp[j[m], 1]]))
        true_h = height(tp[j, 1], exp.window)
        on_boundary = m & (np.abs(true_h - np.round(true_h)) < ON_BOUNDARY)
        for key in counts:
            x, y = s.x.copy(), s.y.copy()
            if key in ("true_x", "true_xy"):
                x[m] = tp[j[m], 0]
            if key in ("true_y", "true_xy"):
                y[m] = tp[j[m], 1]
            if key == "true_y_on_boundaries":
                y[on_boundary] = tp[j[on_boundary], 1]
            counts[key].append(layer_counts(x, y, np.zeros(len(x), bool), exp.window)[0])
        inside = m & in_window(s.x, s.y, exp.window) & in_window(tp[j, 0], tp[j, 1], exp.window)
        flipped = inside & (layer_index(s.y, exp.window) != layer_index(tp[j, 1], exp.window))
        flips.append(np.column_stack([np.abs(true_h - np.round(true_h))[flipped], (s.y - tp[j, 1])[flipped]]))
    n = truth.n
    err = {k: round(float(np.mean(np.abs(np.array(v) - n)[n > 0] / n[n > 0])), 4) for k, v in counts.items()}
    rows = np.concatenate(rows)
    flips = np.concatenate(flips)
    across = {"detected": _across_middle([np.column_stack([s.x, s.y]) for s in found], exp.window, d),
              "truth": _across_middle([tp[:, :2] for tp in truth.particles], exp.window, d)}
    return {"detected_minus_truth": _outward(rows, exp.window), "frame_layer_count_error": err,
            "by_height": _by_height(rows, exp.window), "lying_pairs_across_middle": across,
            "layer_flips": {"spheres": len(flips),
                            f"true_centre_within_{ON_BOUNDARY}_D_of_the_boundary": int((flips[:, 0] < ON_BOUNDARY).sum()),
                            "true_distance_from_the_boundary_D_and_dy_px": [
                                [round(float(a), 4), round(float(b), 2)] for a, b in flips[np.argsort(flips[:, 0])]]}}


def touching_pairs(pts: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two ends (k, 2) and (k, 2) and the length [px] (k,) of every pair of ``pts`` (m, 2) closer
    than outline.TOUCHING diameters ``d``."""
    pairs = cKDTree(pts).query_pairs(TOUCHING * d, output_type="ndarray")
    a, b = pts[pairs[:, 0]], pts[pairs[:, 1]]
    return a, b, np.hypot(*(b - a).T)


def _across_middle(frames: list[np.ndarray], win, d: float) -> dict:
    """Median distance [px] of touching lying pairs (line within 26 deg of the horizontal) with one
    sphere either side of the window's middle column, less that of pairs on one side; and how many
    pairs across (centres (m, 2) per frame, pairs inside the window)."""
    x0, y0, x1, y1 = win
    xm = (x0 + x1) / 2
    across, same = [], []
    for pts in frames:
        a, b, length = touching_pairs(pts, d)
        lying = np.abs(b[:, 0] - a[:, 0]) > 0.9 * length
        inside = ((np.minimum(a[:, 0], b[:, 0]) > x0) & (np.maximum(a[:, 0], b[:, 0]) < x1)
                  & (a[:, 1] > y0) & (a[:, 1] < y1))
        cross = np.sign(a[:, 0] - xm) != np.sign(b[:, 0] - xm)
        across.append(length[lying & inside & cross])
        same.append(length[lying & inside & ~cross])
    across, same = np.concatenate(across), np.concatenate(same)
    return {"gap_px": round(float(np.median(across) - np.median(same)), 2), "pairs_across": int(len(across))}


def _by_height(rows: np.ndarray, win) -> dict:
    """Mean y error [px, + down] and outward x error [px] of the spheres in each two layers' band of
    true height above the plate line; rows: (n, 4) true x, y and error dx, dy."""
    x0, y0, x1, y1 = win
    layer = (y1 - rows[:, 1]) / ((y1 - y0) / 15)
    out = {}
    for lo in range(0, 15, 2):
        m = (layer >= lo) & (layer < lo + 2)
        if m.any():
            out[f"layers {lo}-{min(lo + 2, 15)}"] = {
                "spheres": int(m.sum()), "dy_px": round(float(rows[m, 3].mean()), 2),
                "dx_outward_px": round(float((np.sign(rows[m, 0] - (x0 + x1) / 2) * rows[m, 2]).mean()), 2)}
    return out


def outline_fit(folder: Path) -> dict:
    """(c), the outline fit alone: started at the true centres with the true radii, where it moves them
    (3 iterations, as the detector), and where its edge finder puts the rim, by direction, against the
    true outline's radius, for spheres near the window's left / right side and in its middle column, and
    for those in the middle 60 % of its width in the three layers nearest the plate and the lid."""
    from granseg.measure.detect import _smooth
    from granseg.measure.outline import RIM_SEARCH_PX, RIM_SEARCH_SIZE, _sample, fit_outlines
    from granseg.measure.wall import remove_wall_glare

    truth = load_fixture(folder)
    exp = load_experiment(folder / "experiment.json")
    worker = pipeline._FrameWorker(exp, truth.images[0].shape[1::-1])
    worker.learn(truth.images[0])
    d = exp.particle_diameter_px
    x0, y0, x1, y1 = exp.window
    xm, ym = (x0 + x1) / 2, (y0 + y1) / 2
    rows, edges = [], {"left": [], "middle": [], "right": [], "lowest three layers": [], "top three layers": []}
    n_rays = 48
    theta = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    for tp, img in zip(truth.particles, truth.images, strict=True):
        crop, _ = remove_wall_glare(worker.undistort(img), d, worker.bed_rows)
        tp = tp[tp[:, 4] > 0]
        start, radius = tp[:, :2] - worker.crop[:2], tp[:, 2] / 2
        # each sphere on the image of its material's polarity: with a polarity
        # per material the heavy band's templates come first (detect.learn_templates)
        signs = worker.templates.signs
        sign = np.where(tp[:, 3] > 0, signs[0], signs[-1]).astype(int)
        smooths = _smooth(crop, d, signs)
        moved = np.zeros_like(start)
        for s in np.unique(sign):
            mine = sign == s
            moved[mine] = fit_outlines(smooths[int(s)], start[mine], radius[mine], d).centres - start[mine]
        rows.append(np.column_stack([tp[:, :2], moved]))
        smooth = smooths[int(signs[-1])]  # the rims below: the light material's polarity (one on the looks studied)
        # the edge finder of fit_outlines, once, from the true centres
        steps = np.arange(0.65 * radius.max(), 1.4 * radius.max(), 0.5)
        px = start[:, 0, None, None] + steps * np.cos(theta)[None, :, None]
        py = start[:, 1, None, None] + steps * np.sin(theta)[None, :, None]
        m, k, n_s = px.shape
        prof = _sample(smooth, px.reshape(m * k, n_s), py.reshape(m * k, n_s))
        drop = (prof[:, :-2] - prof[:, 2:]) / 2.0
        width = max(3, int(0.3 * d) | 1)
        sharp = drop - cv2.filter2D(drop, -1, np.ones((1, width), np.float32) / width,
                                    borderType=cv2.BORDER_REPLICATE)
        sharp = sharp.reshape(m, k, n_s - 2)
        band = RIM_SEARCH_PX + RIM_SEARCH_SIZE * radius
        sharp = np.where(np.abs(steps[1:-1][None, None] - radius[:, None, None]) <= band[:, None, None], sharp,
                         -np.inf)
        edge = steps[1:-1][np.argmax(sharp, axis=2)] - radius[:, None]
        centre_rows = np.abs(tp[:, 1] - ym) < 150
        # by height: the middle 60 % of the width, the three layers nearest the plate and the lid
        layer, central = (y1 - tp[:, 1]) / ((y1 - y0) / 15), np.abs(tp[:, 0] - xm) < 0.3 * (x1 - x0)
        for name, sel in (("left", tp[:, 0] < x0 + BAND), ("right", tp[:, 0] > x1 - BAND),
                          ("middle", (np.abs(tp[:, 0] - xm) < BAND) & centre_rows),
                          ("lowest three layers", central & (layer < 3)), ("top three layers", central & (layer >= 12))):
            edges[name].append(edge[sel])
    by_angle = {name: {f"{int(a)}deg": round(float(np.concatenate(v)[:, i].mean()), 2)
                       for i, a in zip(range(0, n_rays, 6), np.degrees(theta[::6]), strict=True)}
                for name, v in edges.items()}
    return {"fit_from_truth_minus_truth": _outward(np.concatenate(rows), exp.window),
            "rim_minus_true_radius_by_direction (0deg = +x, 90deg = +y = down)": by_angle}


def render_control(heavy: str, light: str, out: Path) -> dict:
    """Two frames of one packing under the fixtures' two side panels, without vignetting, and under
    a panel behind the camera; the detector's outward error on each."""
    import granseg.synth.pbr as pbr

    # the side panels at the same angles, 2.2x and 5.6x further away: is it how close they are?
    for dist in FAR_PANELS_MM:
        pbr.LAMPS.setdefault(f"two-sided-{dist:.0f}", [(-55.0, dist), (55.0, dist)])
    result = {}
    for name, kw in (("two side panels", {}), ("two side panels, no vignetting", {"vignetting": 0.0}),
                     *((f"two side panels {dist:.0f} mm from the axis", {"lighting": f"two-sided-{dist:.0f}"})
                       for dist in FAR_PANELS_MM),
                     ("one panel behind the camera", {"lighting": "front"})):
        folder = out / name.replace(" ", "-").replace(",", "")
        pbr.render_pbr_frames(pbr.fixture_map(2, 0.5), heavy=heavy, light=light, image_size=pbr.FIXTURE_SIZE,
                              particle_diameter_px=pbr.FIXTURE_D_PX, noise=0.0, jpeg_quality=None, spp=16,
                              seed=3, out_dir=folder, force=True, **kw)
        result[name] = detector(folder)
        print(f"  control {heavy}/{light}, {name}: {result[name]}", flush=True)
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", type=Path, default=PBR, help="folder of looks (default: the committed fixtures)")
    ap.add_argument("--looks", nargs="+", default=["steel-pom", "pom-pp", "ceramic-pp", "grey-glossy-matte"])
    ap.add_argument("--render", action="store_true", help="also render the lighting control (needs mitsuba)")
    ap.add_argument("--controls-only", action="store_true", help="with --render: only the lighting control")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    missing = [look for look in args.looks if not (args.dir / look / "truth.npz").is_file()]
    if missing:
        ap.error(f"no look {', '.join(missing)} in {args.dir}")
    out = {}
    for look in [] if args.controls_only else args.looks:
        truth = load_fixture(args.dir / look)
        out[look] = {"a_geometry": geometry(truth), "b_camera_round_trip_px": camera_round_trip(truth),
                     "c_detector": detector(args.dir / look), "c_outline_fit": outline_fit(args.dir / look)}
        print(look, out[look], flush=True)
    if args.render:
        with tempfile.TemporaryDirectory() as tmp:
            out["control"] = {f"{h}-{lt}": render_control(h, lt, Path(tmp) / f"{h}-{lt}")
                              for h, lt in (("grey-glossy", "grey-matte"), ("pom", "pp"))}
    if args.json is not None:
        save_json(args.json, {"command": " ".join(sys.argv), "band_px": BAND, "results": out}, force=True)


if __name__ == "__main__":
    main()
