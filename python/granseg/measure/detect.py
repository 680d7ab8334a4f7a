"""Find every sphere in an image of the packed bed, centres to sub-pixel accuracy.

Two stages. OpenCV's Hough circle transform, run at a scale where a sphere is
about 28 px across and with radii bracketing ``particle_diameter_px``, proposes
candidate circles generously. Each candidate is then refined on the full
resolution image: along rays from the candidate centre the sphere's outline is
where the brightness falls fastest outward (the rim darkens towards the dark
gaps or a neighbour's rim; a glass sphere's dark outline behaves the same),
searched between 0.6 and 1.25 radii so that specular highlights near the centre
do not count. A robust circle fit through those outline points gives the
centre. Duplicates and ghosts (circles spanning several spheres) are removed by
keeping the best-fitting circle within 0.7 diameter.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

__all__ = ["Templates", "detect_particles", "learn_templates", "match_templates", "outline_centres",
           "refine_circles",
           "ring_centre", "to_gray"]

HOUGH_DIAMETER_PX = 28.0  # Hough runs at a scale where spheres are about this wide
N_RAYS = 40
KEEP_FRACTION = 0.3  # correlation peaks weaker than this share of their group's median are dropped
SMOOTH_SIGMA_PX = 0.5  # blur of the grey image that detection works on [px]
TEMPLATE_HALF = 0.75  # template half-size [d]: the sphere, its outline and the gaps around it


def to_gray(image: np.ndarray) -> np.ndarray:
    """Luminance of a BGR (or already grey) uint8 image, as float32 in [0, 255]."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image.astype(np.float32)


@dataclass(frozen=True)
class Templates:
    """Mean appearance of each kind of sphere, learned once and reused for every frame.

    patches: per appearance group, the mean grey patch (float32, side 2 half + 1);
    offsets: (k, 2) position of the sphere centre relative to the patch middle [px];
    radii: (k,) sphere radius [px]; d: particle diameter [px].
    """

    patches: tuple[np.ndarray, ...]
    offsets: np.ndarray
    radii: np.ndarray
    d: float

    @property
    def half(self) -> int:
        return int(np.ceil(TEMPLATE_HALF * self.d))

    def shifted(self, group: int, dy: float) -> Templates:
        """The same templates with group ``group``'s centre moved by ``dy`` [px] (down positive)."""
        offsets = self.offsets.copy()
        offsets[group, 1] += dy
        return replace(self, offsets=offsets)


def _smooth(image: np.ndarray, d: float) -> np.ndarray:
    """Grey image with a light blur against noise.

    No more than 0.5 px: blur pulls the outline edge found on a sphere's
    shadowed side inwards (its shading falls towards the edge), and so
    shifts centres towards the lamp (measured: ceramic under a side lamp
    0.23 px up at 0.95 px blur, 0.17 px at 0.5 px, 0.42 px at 1.5 px).
    """
    return cv2.GaussianBlur(to_gray(image), (0, 0), SMOOTH_SIGMA_PX)


def learn_templates(image: np.ndarray, particle_diameter_px: float) -> Templates | None:
    """Learn the spheres' appearances from one image (None if it shows fewer than 3 spheres).

    Hough circles and blobs propose spheres, outline fits confirm them, and
    the mean patch of each colour group of confirmed spheres becomes a
    template.
    """
    d = float(particle_diameter_px)
    smooth = _smooth(image, d)
    candidates = _candidates(to_gray(image), d)
    if candidates.size == 0:
        return None
    seeds = _select(refine_circles(smooth, candidates, d), d)
    if len(seeds) < 3:
        return None
    half = int(np.ceil(TEMPLATE_HALF * d))
    return _templates(smooth, image, seeds[:, :2], d, half)


def detect_particles(image: np.ndarray, particle_diameter_px: float, templates: Templates | None = None,
                     groups: bool = False) -> np.ndarray:
    """Centres and radii of the spheres in ``image``.

    Parameters
    ----------
    image : (H, W, 3) BGR or (H, W) grey uint8 image (undistorted).
    particle_diameter_px : expected sphere diameter [px].
    templates : appearances from :func:`learn_templates` (learned from
        ``image`` itself when None); reuse them across the frames of a run.
    groups : also return the template (appearance group) index of each sphere.

    Returns
    -------
    (m, 4) float array: x, y [px, pixel centres at integers], radius [px] and
    the template correlation in [-1, 1]; (m, 5) with the group index when
    ``groups``.
    """
    d = float(particle_diameter_px)
    if templates is None:
        templates = learn_templates(image, d)
        if templates is None:
            return np.zeros((0, 5 if groups else 4))
    smooth = _smooth(image, d)
    found = _correlation_peaks(smooth, templates, d)
    found[:, :2] = outline_centres(smooth, found[:, :2], found[:, 2], d)
    return found if groups else found[:, :4]


def _candidates(gray: np.ndarray, d: float) -> np.ndarray:
    """Candidate centres (x, y) in full-resolution pixels: Hough circles and bright blobs.

    Both run on a locally contrast-normalised copy at reduced scale, so that
    dark spheres (POM) are found as readily as bright ones.
    """
    scale = min(1.0, HOUGH_DIAMETER_PX / d)
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else gray
    norm = _local_contrast(small, d * scale)
    found = np.concatenate([_hough(norm, d * scale), _blobs(norm, d * scale)])
    # scaled pixel centres -> full-resolution pixel centres
    return (found + 0.5) / scale - 0.5


def _local_contrast(img: np.ndarray, d: float) -> np.ndarray:
    """Brightness in units of the local spread over about two diameters, as uint8."""
    mean = cv2.GaussianBlur(img, (0, 0), d)
    var = cv2.GaussianBlur((img - mean) ** 2, (0, 0), d)
    z = (img - mean) / np.sqrt(var + 4.0)
    return np.clip(128 + 50 * z, 0, 255).astype(np.uint8)


def _hough(norm: np.ndarray, d: float) -> np.ndarray:
    r = 0.5 * d
    smooth = cv2.GaussianBlur(norm, (0, 0), 1.0)
    found = cv2.HoughCircles(
        smooth, cv2.HOUGH_GRADIENT, dp=1, minDist=0.45 * d, param1=60, param2=max(6.0, 0.22 * 2 * np.pi * r),
        minRadius=int(np.floor(0.75 * r)), maxRadius=int(np.ceil(1.2 * r)),
    )
    return np.zeros((0, 2)) if found is None else found.reshape(-1, 3)[:, :2].astype(float)


def _blobs(norm: np.ndarray, d: float) -> np.ndarray:
    """Local maxima of a difference of Gaussians tuned to sphere size."""
    img = norm.astype(np.float32)
    dog = cv2.GaussianBlur(img, (0, 0), 0.25 * d) - cv2.GaussianBlur(img, (0, 0), 0.6 * d)
    size = max(3, int(0.5 * d) | 1)
    peaks = (dog >= cv2.dilate(dog, np.ones((size, size), np.uint8))) & (dog > 0)
    ys, xs = np.nonzero(peaks)
    return np.column_stack([xs, ys]).astype(float)


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
    prof = cv2.remap(smooth, px.reshape(m * k, s).astype(np.float32),
                     py.reshape(m * k, s).astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(m, k, s)
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


def _select(circles: np.ndarray, d: float) -> np.ndarray:
    """Drop implausible fits, then keep the best circle within 0.7 diameter."""
    ok = (circles[:, 2] > 0.3 * d) & (circles[:, 2] < 0.7 * d) & (circles[:, 4] >= 0.5)
    ok &= np.all(np.isfinite(circles), axis=1)
    circles = circles[ok]
    if circles.size == 0:
        return np.zeros((0, 4))
    quality = circles[:, 3] * circles[:, 4]
    order = np.argsort(-quality)
    kept: list[int] = []
    for i in order:
        if kept:
            dist = np.hypot(*(circles[kept, :2] - circles[i, :2]).T)
            if dist.min() < 0.7 * d:
                continue
        kept.append(i)
    out = circles[kept]
    weak = out[:, 3] * out[:, 4] < 0.25 * np.median(out[:, 3] * out[:, 4])
    return out[~weak][:, :4]


# --------------------------------------------------------------------------- final centres


def outline_centres(smooth: np.ndarray, centres: np.ndarray, radii: np.ndarray, d: float,
                    iterations: int = 3, n_rays: int = 48) -> np.ndarray:
    """Centres (m, 2) of circles about the known radii fitted to the spheres' outlines.

    Template peaks and brightness are shifted by shading and highlights, the
    silhouette is not. Along ``n_rays`` rays from each approximate centre the
    outline is the sharpest outward brightness drop within 0.86-1.16 radii:
    the drop per 0.5 px minus its mean over 0.15 d around, so that the smooth
    fall of shading towards a sphere's dark side does not count, only the
    step at its edge. A robust least-squares fit of a
    circle to those edge points moves the centre (clipped to 3 px per
    iteration); rays count by the strength of their edge, and rays whose edge
    disagrees are left out. The radius is fitted
    too (sizes spread by a few per cent; with the radius fixed, a sphere 3 %
    larger than the template is pulled 0.5 px towards the side where
    neighbours hide its outline).
    """
    c = np.asarray(centres, dtype=float).copy()
    if len(c) == 0:
        return c
    radius = np.asarray(radii, dtype=float)
    theta = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    ray = np.column_stack([np.cos(theta), np.sin(theta)])
    r_max = float(radius.max())
    steps = np.arange(0.65 * r_max, 1.4 * r_max, 0.5)
    mid = steps[1:-1]
    window = max(3, int(0.3 * d) | 1)  # 0.15 d in 0.5 px samples
    kernel = np.ones(window, np.float32) / window
    a = np.column_stack([ray, np.ones(n_rays)])[None].repeat(len(c), 0)  # dx, dy, d radius
    for _ in range(iterations):
        px = c[:, 0, None, None] + steps[None, None, :] * ray[None, :, 0, None]
        py = c[:, 1, None, None] + steps[None, None, :] * ray[None, :, 1, None]
        m, k, s = px.shape
        prof = cv2.remap(smooth, px.reshape(m * k, s).astype(np.float32), py.reshape(m * k, s).astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        drop = (prof[:, :-2] - prof[:, 2:]) / 2.0
        sharp = drop - cv2.filter2D(drop, -1, kernel[None, :], borderType=cv2.BORDER_REPLICATE)
        sharp = sharp.reshape(m, k, s - 2)
        allowed = (mid[None, None, :] >= 0.86 * radius[:, None, None]) & (mid[None, None, :] <= 1.16 * radius[:, None, None])
        sharp = np.where(allowed, sharp, -np.inf)
        best = np.argmax(sharp, axis=2)
        peak = np.take_along_axis(sharp, best[..., None], 2)[..., 0]
        lo = np.take_along_axis(sharp, np.clip(best - 1, 0, s - 3)[..., None], 2)[..., 0]
        hi = np.take_along_axis(sharp, np.clip(best + 1, 0, s - 3)[..., None], 2)[..., 0]
        ok = np.isfinite(peak) & (peak > 0)
        lo, hi = np.where(np.isfinite(lo), lo, peak), np.where(np.isfinite(hi), hi, peak)
        denom = np.where(ok, lo - 2 * peak + hi, -1.0)
        frac = np.where(ok & (np.abs(denom) > 1e-6), 0.5 * (lo - hi) / np.where(denom == 0, -1.0, denom), 0.0)
        edge = mid[best] + 0.5 * np.clip(np.nan_to_num(frac), -0.5, 0.5) - radius[:, None]
        # rays weighted by edge strength: where a sphere touches a neighbour
        # its outline is faint and least trustworthy
        wt = np.where(ok, peak, 0.0)
        wt = wt / np.maximum(wt.mean(axis=1, keepdims=True), 1e-9)
        w = ok.astype(float) * wt
        for _ in range(3):
            aw = a * w[..., None]
            ata = np.einsum("mki,mkj->mij", aw, a) + 1e-6 * np.eye(3)
            sol = np.linalg.solve(ata, np.einsum("mki,mk->mi", aw, edge)[..., None])[..., 0]
            resid = np.abs(edge - np.einsum("mki,mi->mk", a, sol))
            scale = np.maximum(0.7, 2.5 * np.median(resid, axis=1, keepdims=True))
            w = (ok & (resid < scale)).astype(float) * wt
        good = (w > 0).sum(axis=1) >= 6
        c[good] += np.clip(sol[good, :2], -3.0, 3.0)
    return c


# --------------------------------------------------------------------------- templates


def match_templates(smooth: np.ndarray, image: np.ndarray, seeds: np.ndarray, d: float) -> np.ndarray:
    """Find spheres as matches of their own mean appearance, learned from ``seeds``.

    Spheres of one material under fixed lamps look alike: the mean of many
    patches shows one sphere against averaged surroundings, and a circle of
    about the nominal diameter fitted to its outline fixes where the
    template's centre is. The grey image ``smooth`` (blurred, float32) is
    correlated with the mean appearance of each of two appearance groups
    (told apart by colour in the BGR ``image``: the two materials); each
    local correlation peak is a sphere, placed to sub-pixel accuracy.
    Returns (m, 5): x, y, radius [px], correlation in [-1, 1], group.
    """
    templates = _templates(smooth, image, seeds[:, :2], d, int(np.ceil(0.75 * d)))
    return _correlation_peaks(smooth, templates, d)


def _templates(smooth, image, centres, d, half) -> Templates:
    """Mean grey patch per appearance group, with the offset of its centre and its radius."""
    size = 2 * half + 1
    patches = np.stack([cv2.getRectSubPix(smooth, (size, size), (float(x), float(y)))
                        for x, y in centres])
    groups = _appearance_groups(image, centres, d)
    means, offsets, radii = [], [], []
    for g in np.unique(groups):
        mean = np.ascontiguousarray(patches[groups == g].mean(axis=0), dtype=np.float32)
        x, y, r = ring_centre(mean, d)
        means.append(mean)
        offsets.append([x - half, y - half])
        radii.append(r)
    return Templates(tuple(means), np.array(offsets, dtype=float), np.array(radii, dtype=float), float(d))


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
    flat = np.concatenate([xin, xout], axis=2).reshape(n * m, 2 * k, 2).astype(np.float32)
    vals = cv2.remap(patch, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(n, m, 2 * k)
    return (vals[..., :k] - vals[..., k:]).mean(axis=2)


def _appearance_groups(image: np.ndarray, centres: np.ndarray, d: float) -> np.ndarray:
    """Split spheres into two groups by the mean colour of their middle (2-means)."""
    img = image if image.ndim == 3 else image[..., None]
    h, w = img.shape[:2]
    xi = np.clip(np.rint(centres[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.rint(centres[:, 1]).astype(int), 0, h - 1)
    k = max(1, int(0.25 * d))
    blurred = cv2.blur(img.astype(np.float32), (2 * k + 1, 2 * k + 1))
    colour = blurred.reshape(h, w, -1)[yi, xi]
    if len(colour) < 4 or np.ptp(colour, axis=0).max() < 1e-3:
        return np.zeros(len(colour), dtype=int)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1)
    _, labels, _ = cv2.kmeans(colour.astype(np.float32), 2, None, crit, 3, cv2.KMEANS_PP_CENTERS)
    labels = labels.ravel()
    if min(np.bincount(labels, minlength=2)) < 3:
        return np.zeros(len(colour), dtype=int)
    return labels


def _correlation_peaks(smooth: np.ndarray, templates: Templates, d: float) -> np.ndarray:
    """Local maxima of the best template correlation, refined to sub-pixel: (m, 5)."""
    half = templates.half
    pad = half + 2
    padded = cv2.copyMakeBorder(smooth, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    maps = np.stack([cv2.matchTemplate(padded, t, cv2.TM_CCOEFF_NORMED) for t in templates.patches])
    best = np.argmax(maps, axis=0) if len(maps) > 1 else np.zeros(maps.shape[1:], dtype=int)
    score = maps.max(axis=0)
    size = max(3, int(0.6 * d) | 1)
    peak = (score >= cv2.dilate(score, np.ones((size, size), np.uint8))) & (score > 0.2)
    ys, xs = np.nonzero(peak)
    inner = (xs > 0) & (ys > 0) & (xs < score.shape[1] - 1) & (ys < score.shape[0] - 1)
    ys, xs = ys[inner], xs[inner]
    fx = _parabola(score[ys, xs - 1], score[ys, xs], score[ys, xs + 1])
    fy = _parabola(score[ys - 1, xs], score[ys, xs], score[ys + 1, xs])
    group = best[ys, xs]
    offset = templates.offsets[group]
    radius = templates.radii[group]
    # top-left of the template in padded coordinates -> centre in image pixels
    x = xs + fx + half - pad + offset[:, 0]
    y = ys + fy + half - pad + offset[:, 1]
    found = np.column_stack([x, y, radius, score[ys, xs], group])
    return _keep_spheres(found, d)


def _parabola(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    denom = a - 2 * b + c
    safe = np.where(np.abs(denom) > 1e-9, denom, -1.0)
    return np.clip(0.5 * (a - c) / safe, -0.5, 0.5)


def _keep_spheres(found: np.ndarray, d: float) -> np.ndarray:
    """Best peak within 0.7 diameter; drop peaks far weaker than a typical sphere.

    "Far weaker" is below 0.3 of the group's median correlation: with the
    templates learned on the first frame, a material's correlation falls as
    the bed mixes and its neighbours change (steel among white ceramic: median
    0.78 on the first frame, 0.5 four frames later), and real spheres then
    score 0.23-0.31 (measured on the synthetic looks, issue 3).
    """
    order = np.argsort(-found[:, 3])
    kept: list[int] = []
    for i in order:
        if kept and np.hypot(*(found[kept, :2] - found[i, :2]).T).min() < 0.7 * d:
            continue
        kept.append(i)
    out = found[kept]
    keep = np.zeros(len(out), dtype=bool)
    for g in np.unique(out[:, 4]):
        mine = out[:, 4] == g
        keep |= mine & (out[:, 3] > KEEP_FRACTION * np.median(out[mine, 3]))
    return out[keep]
