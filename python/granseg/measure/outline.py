"""Sphere centres from their outlines: circles fitted to where the brightness falls at the rim.

:func:`refine_circles` confirms rough candidates (rim searched widely, radius
free); :func:`fit_outlines` places spheres found by their templates to a
few tenths of a pixel and tells how sharp their rims are; :func:`ring_centre`
finds the sphere in a mean patch. All take images in which the spheres are
brighter than their surroundings (the detector inverts the grey image when
they are darker, :func:`granseg.measure.detect._smooth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree
from sklearn.linear_model import QuantileRegressor

__all__ = ["MIN_MIXED_PAIRS", "N_FIT_RAYS", "Outlines", "class_shift", "fit_outlines", "outline_bias", "outline_centres",
           "refine_circles", "ring_centre"]

N_RAYS = 40
# The rim is searched within RIM_SEARCH_PX + RIM_SEARCH_SIZE x radius of the
# expected radius: the start's error and the blur (about 1.5 px), plus the
# spread of sizes (ceramic: d10-d90 = 5.6-6.3 mm, +-6 %). A band in proportion
# to the radius alone (it was +-14 %) reached, on 60 px spheres, the dark lower
# rim of POM and the terminator of PP, 4 px inside: p95 centre error 2.4 and
# 1.1 px, against 1.2 and 0.24 px now; unchanged at 20-30 px (issue 3).
RIM_SEARCH_PX = 1.5
RIM_SEARCH_SIZE = 0.06
N_FIT_RAYS = 48  # rays of :func:`fit_outlines`


def refine_circles(smooth: np.ndarray, centres: np.ndarray, particle_diameter_px: float,
                   iterations: int = 3) -> np.ndarray:
    """Refine approximate centres by fitting circles to the spheres' outlines.

    ``smooth`` is a float32 grey image (lightly blurred), ``centres`` (m, 2)
    approximate x, y [px]. Returns (m, 5): x, y, radius [px], score (median
    outward brightness drop at the outline, grey levels per px) and the share
    of rays that agree with the fitted circle.
    """
    c = np.asarray(centres, dtype=float).copy()
    result = np.zeros((c.shape[0], 5))
    for _ in range(iterations):
        result = _fit_outline(smooth, c, particle_diameter_px)
        moved = np.hypot(*(result[:, :2] - c).T)
        c = np.where((moved < 0.3 * particle_diameter_px)[:, None], result[:, :2], c)
    return result


def _fit_outline(smooth: np.ndarray, c: np.ndarray, d: float) -> np.ndarray:
    radius = 0.5 * d
    theta = np.linspace(0, 2 * np.pi, N_RAYS, endpoint=False)
    cos, sin = np.cos(theta), np.sin(theta)
    steps = np.arange(0.6 * radius, 1.25 * radius, 0.5)
    px = c[:, 0, None, None] + steps[None, None, :] * cos[None, :, None]
    py = c[:, 1, None, None] + steps[None, None, :] * sin[None, :, None]
    m, k, s = px.shape
    prof = _sample(smooth, px.reshape(m * k, s), py.reshape(m * k, s)).reshape(m, k, s)
    drop = (prof[:, :, :-2] - prof[:, :, 2:]) / 2.0  # outward brightness drop per 0.5 px
    best = np.argmax(drop, axis=2)
    peak = np.take_along_axis(drop, best[..., None], 2)[..., 0]
    lo = np.take_along_axis(drop, np.clip(best - 1, 0, s - 3)[..., None], 2)[..., 0]
    hi = np.take_along_axis(drop, np.clip(best + 1, 0, s - 3)[..., None], 2)[..., 0]
    denom = lo - 2 * peak + hi
    frac = np.where(np.abs(denom) > 1e-6, 0.5 * (lo - hi) / np.where(denom == 0, 1, denom), 0.0)
    r_edge = steps[0] + 0.5 * (best + 1 + np.clip(frac, -0.5, 0.5))
    ex = c[:, 0, None] + r_edge * cos
    ey = c[:, 1, None] + r_edge * sin
    return _robust_circles(ex, ey, np.clip(peak, 0, None) * 2.0)


def _robust_circles(ex: np.ndarray, ey: np.ndarray, strength: np.ndarray) -> np.ndarray:
    """Weighted algebraic circle fits (m at once), refitted without outlier rays."""
    w = (strength > 0).astype(float) * np.sqrt(strength)
    fit = _kasa(ex, ey, w)
    for _ in range(2):
        resid = np.abs(np.hypot(ex - fit[:, 0, None], ey - fit[:, 1, None]) - fit[:, 2, None])
        scale = np.maximum(1.0, 2.5 * np.median(resid, axis=1, keepdims=True))
        inlier = (resid < scale) & (strength > 0)
        fit = _kasa(ex, ey, w * inlier)
    share = inlier.mean(axis=1)
    score = np.median(np.where(inlier, strength, 0.0), axis=1)
    return np.column_stack([fit, score, share])


def _kasa(ex: np.ndarray, ey: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Least-squares circles x^2 + y^2 + a x + b y + c = 0; returns (m, 3): x, y, r."""
    mx = (w * ex).sum(1) / np.maximum(w.sum(1), 1e-9)
    my = (w * ey).sum(1) / np.maximum(w.sum(1), 1e-9)
    u, v = ex - mx[:, None], ey - my[:, None]
    a = np.stack([u, v, np.ones_like(u)], axis=2) * w[..., None]
    b = -(u * u + v * v) * w
    ata = np.einsum("mki,mkj->mij", a, a) + 1e-9 * np.eye(3)
    atb = np.einsum("mki,mk->mi", a, b)
    sol = np.linalg.solve(ata, atb[..., None])[..., 0]
    cx, cy = -sol[:, 0] / 2, -sol[:, 1] / 2
    r = np.sqrt(np.maximum(cx * cx + cy * cy - sol[:, 2], 0.0))
    return np.column_stack([cx + mx, cy + my, r])


@dataclass(frozen=True)
class Outlines:
    """Circles fitted to spheres' outlines by :func:`fit_outlines` (m spheres, k rays).

    centres: (m, 2) x, y [px]; radius: (m,) fitted radius [px] (the expected
    one where too few rays agreed); strength: (m, k) sharpness of each ray's
    edge (outward drop per px less its local mean; 0 where none);
    inlier: (m, k) the rays whose edge agrees with the fitted circle;
    step: (m,) how far [px] the last iteration moved each centre (small once
    the fit has settled); residual: (m, k) how far [px] each ray's edge lies
    outside the fitted circle in the last iteration (NaN where the ray found
    none), after ``ray_bias`` is taken off.
    """

    centres: np.ndarray
    radius: np.ndarray
    strength: np.ndarray
    inlier: np.ndarray
    step: np.ndarray
    residual: np.ndarray


def outline_centres(smooth: np.ndarray, centres: np.ndarray, radii: np.ndarray, d: float,
                    iterations: int = 3, n_rays: int = N_FIT_RAYS) -> np.ndarray:
    """Centres (m, 2) of circles about the known radii fitted to the spheres' outlines (:func:`fit_outlines`)."""
    return fit_outlines(smooth, centres, radii, d, iterations, n_rays).centres


def fit_outlines(smooth: np.ndarray, centres: np.ndarray, radii: np.ndarray, d: float,
                 iterations: int = 3, n_rays: int = N_FIT_RAYS, ray_bias: np.ndarray | None = None,
                 free_radius: bool = True) -> Outlines:
    """Circles about the known radii fitted to the spheres' outlines.

    Template peaks and brightness are shifted by shading and highlights, the
    silhouette is not. Along ``n_rays`` rays from each approximate centre the
    outline is the sharpest outward brightness drop near the expected radius
    (RIM_SEARCH_PX + RIM_SEARCH_SIZE radii either side):
    the drop per 0.5 px minus its mean over 0.15 d around, so that the smooth
    fall of shading towards a sphere's dark side does not count, only the
    step at its edge. A robust least-squares fit of a
    circle to those edge points moves the centre (clipped to 3 px per
    iteration); rays count by the strength of their edge, and rays whose edge
    disagrees are left out. The radius is fitted
    too (sizes spread by a few per cent; with the radius fixed, a sphere 3 %
    larger than the template is pulled 0.5 px towards the side where
    neighbours hide its outline).

    ``ray_bias`` ((k,) or (m, k), ray i at angle 2 pi i / k, y down) is
    where the edge finder puts each ray's edge outside the true outline [px],
    taken off before the fit: a sphere's shaded side has no sharp rim, and
    the edge found there lies inside it (:func:`outline_bias`).

    ``free_radius=False`` keeps each radius at ``radii`` and moves the
    centre only. The detector does not use it: placing the spheres with the
    nominal radius was measured and dropped (benches/bench_nominal_radius.py,
    BENCHMARKS.md).

    ``smooth`` must show the spheres brighter than their surroundings (the
    detector passes the inverted image when they are darker).
    """
    c = np.asarray(centres, dtype=float).copy()
    radius = np.asarray(radii, dtype=float)
    if ray_bias is not None and np.shape(ray_bias)[-1] != n_rays:
        raise ValueError(f"ray_bias: {np.shape(ray_bias)[-1]} rays given for a fit of {n_rays}")
    if len(c) == 0:
        empty = np.zeros((0, n_rays))
        return Outlines(c.reshape(0, 2), radius.copy(), empty, empty.astype(bool), np.zeros(0), empty)
    fitted = radius.copy()
    theta = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    ray = np.column_stack([np.cos(theta), np.sin(theta)])
    r_max = float(radius.max())
    window = max(3, int(0.3 * d) | 1)  # 0.15 d in 0.5 px samples
    kernel = np.ones(window, np.float32) / window
    a = np.column_stack([ray, np.full(n_rays, float(free_radius))])[None].repeat(len(c), 0)  # dx, dy, d radius
    band = RIM_SEARCH_PX + RIM_SEARCH_SIZE * radius  # how far from the expected radius the rim may lie
    steps = _reach(np.arange(0.65 * r_max, 1.4 * r_max, 0.5), radius, band, window)
    mid = steps[1:-1]
    # -inf where a drop lies outside the band about the sphere's radius (rays share it): added, not
    # masked with np.where, each iteration
    outside = np.where(np.abs(mid[None, :] - radius[:, None]) <= band[:, None], 0.0, -np.inf)[:, None, :]
    outside = outside.astype(np.float32)
    for _ in range(iterations):
        px = c[:, 0, None, None] + steps[None, None, :] * ray[None, :, 0, None]
        py = c[:, 1, None, None] + steps[None, None, :] * ray[None, :, 1, None]
        m, k, s = px.shape
        prof = _sample(smooth, px.reshape(m * k, s), py.reshape(m * k, s))
        drop = (prof[:, :-2] - prof[:, 2:]) / 2.0
        sharp = drop - cv2.filter2D(drop, -1, kernel[None, :], borderType=cv2.BORDER_REPLICATE)
        sharp = sharp.reshape(m, k, s - 2)
        sharp += outside
        best = np.argmax(sharp, axis=2)
        peak = np.take_along_axis(sharp, best[..., None], 2)[..., 0]
        lo = np.take_along_axis(sharp, np.clip(best - 1, 0, s - 3)[..., None], 2)[..., 0]
        hi = np.take_along_axis(sharp, np.clip(best + 1, 0, s - 3)[..., None], 2)[..., 0]
        ok = np.isfinite(peak) & (peak > 0)
        lo, hi = np.where(np.isfinite(lo), lo, peak), np.where(np.isfinite(hi), hi, peak)
        denom = np.where(ok, lo - 2 * peak + hi, -1.0)
        frac = np.where(ok & (np.abs(denom) > 1e-6), 0.5 * (lo - hi) / np.where(denom == 0, -1.0, denom), 0.0)
        edge = mid[best] + 0.5 * np.clip(np.nan_to_num(frac), -0.5, 0.5) - radius[:, None]
        if ray_bias is not None:
            edge = edge - ray_bias
        # rays weighted by edge strength: where a sphere touches a neighbour
        # its outline is faint and least trustworthy
        wt = np.where(ok, peak, 0.0)
        wt = wt / np.maximum(wt.mean(axis=1, keepdims=True), 1e-9)
        w = ok.astype(float) * wt
        for _ in range(3):
            aw = a * w[..., None]
            ata = aw.transpose(0, 2, 1) @ a + 1e-6 * np.eye(3)  # a seventh of einsum's time
            sol = np.linalg.solve(ata, np.einsum("mki,mk->mi", aw, edge)[..., None])[..., 0]
            resid = np.abs(edge - np.einsum("mki,mi->mk", a, sol))
            scale = np.maximum(0.7, 2.5 * np.median(resid, axis=1, keepdims=True))
            w = (ok & (resid < scale)).astype(float) * wt
        good = (w > 0).sum(axis=1) >= 6
        move = np.where(good[:, None], np.clip(sol[:, :2], -3.0, 3.0), 0.0)
        c += move
        fitted = np.where(good, radius + sol[:, 2], radius)
    residual = np.where(ok, edge - np.einsum("mki,mi->mk", a, sol), np.nan)
    return Outlines(c, fitted, np.where(ok, peak, 0.0), w > 0, np.hypot(*move.T), residual)


def _reach(steps: np.ndarray, radius: np.ndarray, band: np.ndarray, window: int) -> np.ndarray:
    """The part of the rays' ``steps`` [px] that the rim search can use: the drops within ``band`` of
    some sphere's ``radius`` and half a running mean of ``window`` samples either side of them. The
    edges found are those of the whole span (cut at its ends as before, so the running mean meets
    the same border); for spheres of one size at D = 80 px, 41 samples a ray instead of 60, and the
    frame worker 5 % faster on one thread (87-89 -> 83-84 ms a frame, ``benches/bench_measure.py
    --frame-worker``, BENCHMARKS.md)."""
    mid = steps[1:-1]
    allowed = np.flatnonzero((np.abs(mid[:, None] - radius[None, :]) <= band[None, :]).any(axis=1))
    if not len(allowed):
        return steps
    half = window // 2
    first, last = max(0, allowed[0] - half), min(len(mid) - 1, allowed[-1] + half)
    return steps[first:last + 3]  # drop j uses samples j and j + 2


def outline_bias(residual: np.ndarray) -> np.ndarray:
    """The part of a kind of sphere's outline residuals (m, k) (:class:`Outlines`) that no circle
    explains: (k,) [px] per ray, 0 where fewer than half the spheres' rays found an edge.

    A systematic residual profile p(theta), the median over the spheres,
    is part circle (a shift c_x cos + c_y sin, which the fit has already
    taken as a move of the centre, and a change of radius) and part an
    edge finder that is wrong on some side: the shaded side of a sphere lit
    from above, where no sharp rim separates it from the dark gaps, puts
    the edge up to 1.8 px inside (dark POM of the 2-D renderer's S-POM-25,
    against 0.4-0.85 px on its other sides), which moves the centre 0.2-0.4
    px up. Which part is which is not determined by p alone; assuming the edge
    finder right on most of the outline, the circle part is the
    least-absolute-deviation fit of c_x cos + c_y sin + c_r (its residual
    is sparse, as the bias is) and the rest is the bias.
    """
    n_rays = residual.shape[1]
    enough = np.isfinite(residual).sum(axis=0) >= max(1, residual.shape[0] // 2)
    if enough.sum() < n_rays // 2:
        return np.zeros(n_rays)
    profile = np.nanmedian(np.where(enough, residual, 0.0), axis=0)  # every column has an edge
    theta = 2 * np.pi * np.arange(n_rays) / n_rays
    basis = np.column_stack([np.cos(theta), np.sin(theta)])
    circle = QuantileRegressor(quantile=0.5, alpha=0.0, solver="highs").fit(basis[enough], profile[enough])
    return np.where(enough, profile - circle.predict(basis), 0.0)


# Touching pairs of one heavy and one light sphere, one above the other,
# needed to read the classes' relative shift. The 2-D renderer's looks give
# 140-470 over six frames; on the 140 of C-PP-90 (a tenth light) the shift
# read is noisy (-0.5 px, BENCHMARKS.md); fewer than 100 are not used.
MIN_MIXED_PAIRS = 100
TOUCHING = 1.12  # pair distance [diameters] up to which two spheres are taken as touching


def class_shift(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]], d: float) -> tuple[float, int]:
    """How much higher [px] the light class's centres are found than the heavy class's, from the
    spheres themselves; and the number of pairs it was read from (0.0 where fewer than MIN_MIXED_PAIRS).

    ``frames``: per frame the spheres' x, y [px, y down] and heavy (bool);
    ``d``: the sphere diameter [px].

    The outline bias (:func:`outline_bias`) takes off what no circle
    explains; a shift of a whole class's outlines, the same on every sphere,
    is a circle and stays (the shaded lower side of a matte sphere lit from
    above pulls its centre up: light PP and POM of the 2-D renderer 0.2-0.5 px,
    the steel and ceramic less). It shows between the classes: where a
    light sphere rests on a heavy one the two are found further apart than
    they are by the difference of their shifts (times the cosine of their
    line's angle to the vertical), and where a heavy one rests on a light
    one nearer by as much. Packing does not care which class sits on top,
    so the median distance of touching mixed pairs against sign x cosine
    (+ light above) has that difference as its slope. Which class carries
    how much of it, the pairs cannot tell.
    """
    x_all, y_all = [], []
    for x, y, heavy in frames:
        if len(x) < 2:
            continue
        pts = np.column_stack([x, y])
        pairs = cKDTree(pts).query_pairs(TOUCHING * d, output_type="ndarray")
        if not len(pairs):
            continue
        top = np.where(y[pairs[:, 0]] < y[pairs[:, 1]], pairs[:, 0], pairs[:, 1])
        below = pairs[:, 0] + pairs[:, 1] - top
        v = pts[below] - pts[top]
        dist = np.hypot(v[:, 0], v[:, 1])
        cos = v[:, 1] / np.maximum(dist, 1e-9)
        mixed = (cos > 0.5) & (heavy[top] != heavy[below])
        x_all.append(np.where(heavy[top][mixed], -1.0, 1.0) * cos[mixed])
        y_all.append(dist[mixed])
    sx = np.concatenate(x_all) if x_all else np.zeros(0)
    if len(sx) < MIN_MIXED_PAIRS or np.all(sx > 0) or np.all(sx < 0):
        return 0.0, len(sx)
    return _lad_slope(sx, np.concatenate(y_all), d), len(sx)


def _lad_slope(x: np.ndarray, y: np.ndarray, d: float) -> float:
    """Slope of the least-absolute-deviations line y = a + b x, |b| <= d.

    For a given slope the best intercept is the median of y - b x, and the
    loss left is convex in b, so a bounded scalar search finds its minimum.
    It agrees with the linear program (sklearn's QuantileRegressor, HiGHS) to
    1e-6 px and took 2 ms where that took 1 s on 6000 pairs (a 120-frame
    run: 2.1 s of its 11, BENCHMARKS.md).
    """
    def loss(b: float) -> float:
        r = y - b * x
        return float(np.abs(r - np.median(r)).sum())

    return float(minimize_scalar(loss, bounds=(-d, d), method="bounded", options={"xatol": 1e-7 * d}).x)


def _sample(image: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """``image`` (float32) at the points (px, py) (n, s), bilinear, edges replicated.

    In blocks of rows: cv2.remap takes maps of fewer than 32767 rows (a
    frame's 700 spheres of 48 rays each are more).
    """
    px, py = px.astype(np.float32), py.astype(np.float32)
    out = np.empty(px.shape, np.float32)
    for i in range(0, len(px), 32000):
        out[i:i + 32000] = cv2.remap(image, px[i:i + 32000], py[i:i + 32000], cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)
    return out


def ring_centre(patch: np.ndarray, d: float) -> tuple[float, float, float]:
    """Centre (x, y) and radius [px] of the sphere in the middle of ``patch``.

    The circle of radius within 3 % of d/2 and centre within d/4 of the
    middle across which the brightness falls most, on average, going outward.
    Works on a mean appearance, where the outline is clean.
    """
    h, w = patch.shape
    mid = np.array([(w - 1) / 2, (h - 1) / 2])
    theta = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    ray = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    radii = 0.5 * d * np.linspace(0.97, 1.03, 3)
    best = (-np.inf, mid[0], mid[1], 0.5 * d)
    for step, span in ((1.0, 0.2 * d), (0.2, 1.2)):
        offs = np.arange(-span, span + 1e-9, step)
        ox, oy = np.meshgrid(offs + best[1] - mid[0], offs + best[2] - mid[1])
        cx, cy = (mid[0] + ox).ravel(), (mid[1] + oy).ravel()
        score = _ring_scores(patch, cx, cy, radii, ray)
        i, j = np.unravel_index(np.argmax(score), score.shape)
        best = (score[i, j], cx[i], cy[i], radii[j])
    return float(best[1]), float(best[2]), float(best[3])


def _ring_scores(patch, cx, cy, radii, ray) -> np.ndarray:
    """Mean outward brightness drop on circles (centre i, radius j): (n_centres, n_radii)."""
    pts_in = (radii[None, :, None] - 0.75)[..., None] * ray[None, None]
    pts_out = (radii[None, :, None] + 0.75)[..., None] * ray[None, None]
    base = np.stack([cx, cy], axis=1)[:, None, None, :]
    xin, xout = base + pts_in, base + pts_out
    n, m, k, _ = xin.shape
    flat = np.concatenate([xin, xout], axis=2).reshape(n * m, 2 * k, 2)
    vals = _sample(patch, flat[..., 0], flat[..., 1]).reshape(n, m, 2 * k)
    return (vals[..., :k] - vals[..., k:]).mean(axis=2)
