"""Find every sphere in an image of the packed bed, centres to a few tenths of a pixel.

Learning, once per run (:func:`learn_templates`): OpenCV's Hough circle
transform and a blob detector, run where a sphere is about 28 px across on a
locally contrast-normalised copy (dark spheres count as much as bright ones),
propose spheres generously; circles fitted to their outlines confirm them;
the mean patch of each colour group of confirmed spheres is a first template
(:mod:`granseg.measure.templates`). Those spheres are found again with it and
refined as every frame's are, and the final templates are cut around the
refined centres.

Every frame (:func:`detect_particles`): the spheres are the matches of the
templates over the sphere disk, each given the group its colour belongs to,
and each is placed by a robust circle fit to its outline
(:mod:`granseg.measure.outline`).
"""

from __future__ import annotations

import cv2
import numpy as np

from granseg.measure.outline import outline_centres, refine_circles
from granseg.measure.templates import Templates, build_templates, find_spheres

__all__ = ["Templates", "detect_particles", "learn_templates", "to_gray"]

HOUGH_DIAMETER_PX = 28.0  # Hough runs at a scale where spheres are about this wide
SMOOTH_SIGMA_PX = 0.5  # blur of the grey image that detection works on [px]


def to_gray(image: np.ndarray) -> np.ndarray:
    """Luminance of a BGR (or already grey) uint8 image, as float32 in [0, 255]."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image.astype(np.float32)


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

    The final templates are cut around the confirmed spheres as
    :func:`detect_particles` places them, so that a template's middle is, on
    average, where the outline fit puts a sphere and a match starts the fit
    within its scatter (the first templates' centres, from the mean patch
    alone, were up to 2 px off for dark POM, from where the fit sometimes
    went astray; issue 3).
    """
    d = float(particle_diameter_px)
    smooth = _smooth(image, d)
    candidates = _candidates(to_gray(image), d)
    if candidates.size == 0:
        return None
    seeds = _select(refine_circles(smooth, candidates, d), d)
    if len(seeds) < 3:
        return None
    first = build_templates(smooth, image, seeds[:, :2], d)
    found = find_spheres(smooth, image, first)
    # only confirmed spheres: other matches (at the lid, in voids) would blur the templates
    if len(found):
        gap = np.hypot(*(found[:, None, :2] - seeds[None, :, :2]).transpose(2, 0, 1)).min(axis=1)
        found = found[gap < 0.3 * d]
    if len(found) < 3:
        return first
    refined = outline_centres(smooth, found[:, :2], found[:, 2], d)
    return build_templates(smooth, image, refined, d, centred=True)


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
    the correlation in [-1, 1] of the sphere's disk with its template; (m, 5)
    with the group index when ``groups``.
    """
    d = float(particle_diameter_px)
    if templates is None:
        templates = learn_templates(image, d)
        if templates is None:
            return np.zeros((0, 5 if groups else 4))
    smooth = _smooth(image, d)
    found = find_spheres(smooth, image, templates)
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
