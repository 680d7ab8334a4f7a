"""Heavy or light: each sphere's colour, two colour classes learned from the frames.

No thresholds are tuned by hand. Every sphere is described by the median
colour of its middle in CIE LAB (plus the spread of its lightness, which sets
shiny metal and glass apart from matt plastics). A two-component Student-t
mixture fitted to all spheres of the run finds the two materials; the class
whose spheres sit higher in the first frame is the heavy one, because an
experiment starts with the heavy layer on top. Explicit colour ranges in
``experiment.json`` (``heavy_hsv``, ``light_hsv``, ``heavy_lab``,
``light_lab``: [[lo x3], [hi x3]] in OpenCV's 8-bit scales) override this.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["FEATURES", "ColourClasses", "colour_features", "learn_classes", "classify_by_ranges"]

FEATURES = ("L", "a", "b", "L_spread", "H", "S", "V")
LEARNED = slice(0, 4)  # the LAB features used by the learned classes
_RINGS = ((0.0, 1), (0.22, 6), (0.42, 10))  # sample circles (radius / sphere radius, points)


def colour_features(image: np.ndarray, centres: np.ndarray, particle_diameter_px: float) -> np.ndarray:
    """Colour of the middle of each sphere, (m, 7): median L, a, b; L spread (p90 - p10); median H, S, V.

    ``image`` is BGR uint8, ``centres`` (m, 2) x, y [px]. Values in OpenCV's
    8-bit LAB and HSV scales (H in 0-179).
    """
    if len(centres) == 0:
        return np.zeros((0, len(FEATURES)))
    smooth = cv2.GaussianBlur(image, (0, 0), max(0.7, particle_diameter_px / 40))
    pts = _sample_points(centres, 0.5 * particle_diameter_px)
    m, k = pts.shape[:2]
    # sample the blurred colour first, convert only the samples (converting
    # the whole frame to LAB and HSV cost 50 ms at D = 80 px)
    bgr = cv2.remap(smooth, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    lab = cv2.cvtColor(bgr, cv2.COLOR_BGR2LAB)
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    vals = np.concatenate([lab, hsv], axis=2).astype(np.float32).reshape(m, k, 6)
    med = np.median(vals, axis=1)
    spread = np.percentile(vals[..., 0], 90, axis=1) - np.percentile(vals[..., 0], 10, axis=1)
    hue = _circular_median_hue(vals[..., 3])
    return np.column_stack([med[:, :3], spread, hue, med[:, 4:6]])


def _sample_points(centres: np.ndarray, radius: float) -> np.ndarray:
    offs = [np.zeros((1, 2))]
    for frac, n in _RINGS[1:]:
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        offs.append(frac * radius * np.column_stack([np.cos(t), np.sin(t)]))
    offs = np.concatenate(offs)
    return (centres[:, None, :2] + offs[None]).astype(np.float32)


def _circular_median_hue(h: np.ndarray) -> np.ndarray:
    """Median hue (0-179) that respects the wrap-around at red."""
    ang = h * (2 * np.pi / 180)
    mean = np.arctan2(np.sin(ang).mean(1), np.cos(ang).mean(1))
    dev = (ang - mean[:, None] + np.pi) % (2 * np.pi) - np.pi
    return ((mean + np.median(dev, axis=1)) % (2 * np.pi)) * (180 / (2 * np.pi))


NU = 4.0  # Student-t degrees of freedom: heavy tails for shadowed, highlighted or off-centre spheres


@dataclass(frozen=True)
class ColourClasses:
    """Two Student-t colour classes in the standardised LAB feature space.

    Student-t rather than Gaussian because a material's colour cluster has
    outliers (a sphere in a neighbour's shadow, a highlight, a centre off by a
    pixel or two) while its core can be very tight (a neutral grey: a and b
    within 0.2 levels). A Gaussian class then calls such an outlier, many
    standard deviations out in lightness only, the other material, even when
    its hue says otherwise (dark POM read as glass, issue 3).
    """

    mean: np.ndarray  # (2, 4), row 1 = heavy
    cov: np.ndarray  # (2, 4, 4), scale matrices
    weight: np.ndarray  # (2,)
    scale: np.ndarray  # (4,) feature standardisation

    def is_heavy(self, features: np.ndarray) -> np.ndarray:
        """True where a sphere with these features belongs to the heavy class."""
        if len(features) == 0:
            return np.zeros(0, dtype=bool)
        logp = _log_densities(features[:, LEARNED] / self.scale, self.mean, self.cov, self.weight)
        return logp[:, 1] > logp[:, 0]


def learn_classes(features: np.ndarray, first_frame_features: np.ndarray,
                  first_frame_height: np.ndarray, seed: int = 0) -> ColourClasses:
    """Fit two colour classes to ``features`` (spheres pooled over the run, (m, 7)).

    The heavy class is the one whose spheres sit higher in the first frame:
    ``first_frame_height`` [any unit, up positive] of the spheres with
    ``first_frame_features``. Raises ValueError if the colours do not form
    two classes that differ in height in that frame.
    """
    x = np.asarray(features, dtype=float)[:, LEARNED]
    if len(x) < 10:
        raise ValueError(f"too few spheres ({len(x)}) to learn the two colour classes")
    scale = np.maximum(x.std(axis=0), 1e-3)
    mean, cov, weight = _em(x / scale, seed)
    classes = ColourClasses(mean, cov, weight, scale)
    heavy = classes.is_heavy(first_frame_features)
    if heavy.all() or (~heavy).all():
        raise ValueError("the first frame shows only one colour class; cannot tell heavy from light")
    h = np.asarray(first_frame_height, dtype=float)
    if h[heavy].mean() < h[~heavy].mean():  # swap: the upper class is the heavy one
        classes = ColourClasses(mean[::-1].copy(), cov[::-1].copy(), weight[::-1].copy(), scale)
    return classes


def _em(x: np.ndarray, seed: int, iterations: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-component Student-t mixture (fixed NU) by expectation-maximisation, k-means start.

    Peel & McLachlan (2000): each E-step also weighs every point by
    (NU + p) / (NU + Mahalanobis^2), so outliers pull less on mean and scale.
    """
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    cv2.setRNGSeed(seed)
    _, labels, _ = cv2.kmeans(x.astype(np.float32), 2, None, crit, 4, cv2.KMEANS_PP_CENTERS)
    resp = np.eye(2)[labels.ravel()]
    u = np.ones((len(x), 2))
    for _ in range(iterations):
        mean, cov, weight = _m_step(x, resp, u)
        logp, maha = _log_densities(x, mean, cov, weight, with_distance=True)
        new = np.exp(logp - logp.max(axis=1, keepdims=True))
        new /= new.sum(axis=1, keepdims=True)
        u = (NU + x.shape[1]) / (NU + maha)
        if np.abs(new - resp).max() < 1e-6:
            break
        resp = new
    return mean, cov, weight


def _m_step(x, resp, u):
    nk = resp.sum(axis=0) + 1e-9
    cov = np.empty((2, x.shape[1], x.shape[1]))
    mean = np.empty((2, x.shape[1]))
    for k in range(2):
        w = resp[:, k] * u[:, k]
        mean[k] = w @ x / (w.sum() + 1e-12)
        dx = x - mean[k]
        cov[k] = (w[:, None] * dx).T @ dx / nk[k] + 1e-3 * np.eye(x.shape[1])
    return mean, cov, nk / nk.sum()


def _log_densities(x, mean, cov, weight, with_distance: bool = False):
    """Log of weight x multivariate Student-t density (NU) of each point in each class, (m, 2)."""
    p = x.shape[1]
    out, maha = np.empty((len(x), 2)), np.empty((len(x), 2))
    for k in range(2):
        dx = x - mean[k]
        inv = np.linalg.inv(cov[k])
        _, logdet = np.linalg.slogdet(cov[k])
        maha[:, k] = np.einsum("ij,jk,ik->i", dx, inv, dx)
        out[:, k] = np.log(weight[k]) - 0.5 * logdet - 0.5 * (NU + p) * np.log1p(maha[:, k] / NU)
    return (out, maha) if with_distance else out


def classify_by_ranges(features: np.ndarray, ranges: dict[str, np.ndarray]) -> np.ndarray:
    """Heavy by explicit colour ranges (``heavy_hsv``, ``light_hsv``, ``heavy_lab``, ``light_lab``).

    A sphere is heavy if its median colour lies in a heavy range, or if only
    light ranges are given and it lies in none of them.
    """
    cols = {"lab": features[:, 0:3], "hsv": features[:, 4:7]}

    def inside(key: str) -> np.ndarray:
        lo, hi = ranges[key]
        v = cols[key.split("_")[1]]
        return np.all((v >= lo) & (v <= hi), axis=1)

    heavy_keys = [k for k in ranges if k.startswith("heavy_")]
    light_keys = [k for k in ranges if k.startswith("light_")]
    if heavy_keys:
        return np.any([inside(k) for k in heavy_keys], axis=0)
    return ~np.any([inside(k) for k in light_keys], axis=0)
