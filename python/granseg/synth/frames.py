"""Synthetic side-wall frames of the shear cell, with exact ground truth.

:func:`render_frames` draws what the camera sees through the transparent
outer wall: spheres in a random dense (jammed) packing against the wall,
sheared sideways with the wall-adjacent velocity profile (fast at the bottom
plate, still under the lid), shaded by material (metallic steel, white ceramic,
transparent glass, dark POM, coloured polypropylene), seen through a
barrel-distorting lens given as an OpenCV camera model, with blur, sensor
noise and JPEG artefacts. Which grains are heavy follows a given
concentration map layer by layer, and the exact centres and per-layer counts
come back with the images, so that the measurement pipeline can be tested
against known answers (and users can check their camera settings).

:func:`render_checkerboard` draws a checkerboard seen by the same kind of
camera, for testing camera calibration.

Pixel convention: OpenCV's, pixel centres at integer coordinates, x to the
right, y downward. Ground-truth positions are in *undistorted* pixels (the
coordinates of ``window`` in ``experiment.json``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

__all__ = ["MATERIAL_LOOKS", "RenderedFrames", "default_camera", "render_frames", "render_checkerboard"]

# How each material looks. colour: B, G, R in [0, 1]; kd/ks: diffuse and
# specular weights; shininess: Blinn-Phong exponent; metal: mirror-like
# reflection of the surroundings; glass: transparent, shows the grains behind;
# size_spread: relative standard deviation of the diameter.
MATERIAL_LOOKS: dict[str, dict[str, Any]] = {
    "steel": dict(colour=(0.60, 0.60, 0.62), kd=0.25, ks=0.9, shininess=80, metal=True,
                  glass=False, size_spread=0.004),
    "ceramic": dict(colour=(0.86, 0.88, 0.89), kd=0.9, ks=0.25, shininess=18, metal=False,
                    glass=False, size_spread=0.035),
    "glass": dict(colour=(0.80, 0.93, 0.86), kd=0.05, ks=1.0, shininess=120, metal=False,
                  glass=True, size_spread=0.02),
    "pom": dict(colour=(0.17, 0.17, 0.18), kd=0.9, ks=0.45, shininess=35, metal=False,
                glass=False, size_spread=0.01),
    "pp": dict(colour=(0.16, 0.22, 0.80), kd=0.9, ks=0.35, shininess=25, metal=False,
               glass=False, size_spread=0.008),
}

# Lamp directions (towards the lamp; x right, y down, z towards the camera).
LIGHTINGS: dict[str, list[tuple[float, float, float, float]]] = {
    "two-sided": [(-0.62, -0.25, 0.74, 0.65), (0.62, -0.25, 0.74, 0.65)],
    "left": [(-0.55, -0.35, 0.76, 1.0)],
    "front": [(0.0, 0.0, 1.0, 1.0)],
    "diffuse": [(0.0, -0.3, 0.95, 0.55), (-0.5, 0.2, 0.84, 0.3), (0.5, 0.2, 0.84, 0.3)],
}

PACKING_FRACTION = 0.80  # area share of the wall covered by sphere outlines (hexagonal: 0.907)
RELAX_SWEEPS = 1500  # relaxation sweeps building the initial packing
SHEAR_SWEEPS = 200  # relaxation sweeps after each frame's shear step


@dataclass
class RenderedFrames:
    """Frames as the camera gives them, and their exact ground truth.

    images: list of (H, W, 3) uint8 BGR frames (distorted, noisy, compressed).
    particles: per frame, an (m, 5) float array of every sphere whose centre
        lies within one diameter of the window: x, y [undistorted px],
        diameter [px], heavy (1/0), in_window (1/0).
    n, n_heavy: (n_t, n_layers) int, particles (and heavy ones) whose centre
        is in each layer of the window, layer 0 at the bottom.
    c_raw: (n_t, n_layers) float, n_heavy / n.
    experiment: the ``experiment.json`` content describing these frames.
    paths: files written (frames, then experiment.json), empty if none.
    """

    images: list[np.ndarray]
    particles: list[np.ndarray]
    n: np.ndarray
    n_heavy: np.ndarray
    c_raw: np.ndarray
    experiment: dict[str, Any]
    paths: list[Path] = field(default_factory=list)


def default_camera(image_size: tuple[int, int], k1: float = -0.12) -> tuple[np.ndarray, np.ndarray]:
    """A wide-angle camera model for ``image_size`` = (width, height) [px].

    Returns (camera_matrix 3x3, dist_coeffs k1 k2 p1 p2 k3); ``k1`` < 0 is
    barrel distortion. Focal length 0.9 x width [px].
    """
    w, h = image_size
    f = 0.9 * w
    k = np.array([[f, 0.0, (w - 1) / 2 + 3.0], [0.0, f, (h - 1) / 2 - 2.0], [0.0, 0.0, 1.0]])
    return k, np.array([k1, 0.3 * k1 * k1, 0.0004, -0.0003, 0.0])


def render_frames(
    c: Any,
    *,
    heavy: str = "steel",
    light: str = "pp",
    particle_diameter_px: float = 30.0,
    image_size: tuple[int, int] = (640, 720),
    window: tuple[float, float, float, float] | None = None,
    camera_matrix: Any = None,
    dist_coeffs: Any = None,
    bottom_shift_px: float | None = None,
    delta_over_H: float = 0.18,
    lighting: str = "two-sided",
    exposure: float = 1.0,
    vignetting: float = 0.25,
    blur: float = 0.7,
    noise: float = 2.0,
    jpeg_quality: int | None = None,
    colours: dict[str, tuple[float, float, float]] | None = None,
    fps: float = 0.5,
    seed: int = 0,
    out_dir: str | os.PathLike | None = None,
    experiment: dict[str, Any] | None = None,
    force: bool = False,
) -> RenderedFrames:
    """Render frames whose per-layer heavy share follows the map ``c``.

    Parameters
    ----------
    c : (n_t, n_layers) array in [0, 1]
        Heavy share per layer (layer 0 at the bottom) for each frame; in each
        frame the spheres with their centre in layer j are heavy in the
        proportion c[i, j] (rounded to whole spheres). Frame 0 should have the
        heavy grains on top, as an experiment starts.
    heavy, light : str
        Materials: steel, ceramic, glass, pom, pp (case-insensitive).
    particle_diameter_px : float
        Sphere diameter in undistorted pixels (typ. 20-80).
    image_size : (width, height)
        Sensor size [px].
    window : (x0, y0, x1, y1) or None
        Investigation window in undistorted pixels; default 9 diameters wide
        and 15 high (one diameter per layer), centred. y0 is the lid, y1 the
        bottom plate.
    camera_matrix, dist_coeffs : OpenCV camera model
        Default: :func:`default_camera` (mild barrel distortion).
    bottom_shift_px : float
        Sideways shift of the bottom row between frames [px]; rows higher up
        move by ``bottom_shift_px * exp(-z / (delta_over_H * H))``.
        Default 0.6 diameter.
    lighting : "two-sided" (two side LED lamps), "left", "front" (ring light) or "diffuse".
    exposure : brightness gain (1 = nominal).
    vignetting : relative darkening at the image corners.
    blur : Gaussian blur sigma of the optics [px].
    noise : sensor noise standard deviation [grey levels of 255].
    jpeg_quality : None for lossless PNG frames, else JPEG quality 1-100.
    colours : optional {material: (r, g, b) in [0, 1]} to recolour a material
        (e.g. {"pp": (0.2, 0.4, 0.9)} for blue polypropylene).
    fps : frames per second written to experiment.json [1/s].
    seed : random seed (packing, colours, noise).
    out_dir : if given, frames ``frame_0000.png`` (or ``.jpg``) and
        ``experiment.json`` are written there (atomically; existing files are
        kept unless ``force``).
    experiment : extra or overriding experiment.json fields (e.g. rho_h).

    Returns
    -------
    RenderedFrames with the images, the exact centres and the per-layer counts.
    """
    cmap = _check_map(c)
    heavy_look, light_look = _look(heavy, colours), _look(light, colours)
    d = float(particle_diameter_px)
    if not np.isfinite(d) or d < 8:
        raise ValueError(f"particle_diameter_px must be >= 8 px, got {particle_diameter_px!r}")
    w, h = (int(v) for v in image_size)
    k_mat, dist = _camera(camera_matrix, dist_coeffs, (w, h))
    win = _window(window, d, cmap.shape[1], (w, h))
    rng = np.random.default_rng(seed)
    sensor_map, canvas_box = _distortion_map(k_mat, dist, (w, h), d)
    bed = _Bed(win, d, cmap.shape[1], canvas_box, heavy_look, light_look, rng)
    scene = _Scene(canvas_box, win, d, heavy_look, light_look, lighting, rng)
    shift = 0.6 * d if bottom_shift_px is None else float(bottom_shift_px)
    images, truth = [], []
    n = np.zeros(cmap.shape, dtype=np.int64)
    n_heavy = np.zeros(cmap.shape, dtype=np.int64)
    for i in range(cmap.shape[0]):
        x = bed.positions(i, shift, delta_over_H)
        bed.assign_types(x, cmap[i], rng)
        ideal = scene.draw(x, bed, exposure, vignetting)
        images.append(_camera_effects(ideal, sensor_map, blur, noise, jpeg_quality, rng))
        truth.append(bed.truth(x))
        n[i], n_heavy[i] = bed.layer_counts(x)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_raw = np.where(n > 0, n_heavy / np.maximum(n, 1), np.nan)
    meta = _experiment(heavy, light, cmap, k_mat, dist, win, d, fps, experiment)
    result = RenderedFrames(images, truth, n, n_heavy, c_raw, meta)
    if out_dir is not None:
        result.paths = _write(result, Path(out_dir), jpeg_quality, force)
    return result


# --------------------------------------------------------------------------- inputs


def _check_map(c: Any) -> np.ndarray:
    a = np.asarray(c, dtype=float)
    if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 2:
        raise ValueError(f"c must be a (n_t, n_layers) array, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 1:
        raise ValueError("c must hold finite shares in [0, 1]")
    return a


def _look(name: str, colours: dict[str, tuple[float, float, float]] | None) -> dict[str, Any]:
    key = str(name).strip().lower()
    if key not in MATERIAL_LOOKS:
        raise ValueError(f"unknown material {name!r}; choose from {sorted(MATERIAL_LOOKS)}")
    look = dict(MATERIAL_LOOKS[key], name=key)
    if colours and key in {k.lower() for k in colours}:
        r, g, b = next(v for k, v in colours.items() if k.lower() == key)
        look["colour"] = (float(b), float(g), float(r))
    return look


def _camera(k: Any, dist: Any, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    if k is None and dist is None:
        return default_camera(size)
    k_def, d_def = default_camera(size)
    k_mat = k_def if k is None else np.asarray(k, dtype=float).reshape(3, 3)
    d_vec = d_def if dist is None else np.asarray(dist, dtype=float).ravel()
    return k_mat, d_vec


def _window(window: Any, d: float, n_layers: int, size: tuple[int, int]) -> np.ndarray:
    if window is None:
        w, h = size
        x0, y0 = (w - 9 * d) / 2, (h - n_layers * d) / 2
        return np.array([x0, y0, x0 + 9 * d, y0 + n_layers * d])
    win = np.asarray(window, dtype=float)
    if win.shape != (4,) or not (win[0] < win[2] and win[1] < win[3]):
        raise ValueError(f"window must be (x0, y0, x1, y1) with x0 < x1, y0 < y1, got {window!r}")
    return win


# --------------------------------------------------------------------------- lens


def _distortion_map(k: np.ndarray, dist: np.ndarray, size: tuple[int, int], d: float):
    """For every sensor pixel, the undistorted position it sees; and the canvas box.

    Returns (map (H, W, 2) float32 in canvas pixels, (ox, oy, cw, ch)).
    """
    w, h = size
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)
    und = cv2.undistortPoints(pts, k, dist, P=k, criteria=crit).reshape(h, w, 2)
    lo = np.floor(und.reshape(-1, 2).min(axis=0) - 2 * d)
    hi = np.ceil(und.reshape(-1, 2).max(axis=0) + 2 * d)
    if np.any(hi - lo > 4 * np.array([w, h])) or not np.all(np.isfinite(und)):
        raise ValueError("dist_coeffs: distortion too strong to render (lens model folds over)")
    box = (float(lo[0]), float(lo[1]), int(hi[0] - lo[0]), int(hi[1] - lo[1]))
    return (und - lo).astype(np.float32), box


def _camera_effects(ideal: np.ndarray, sensor_map: np.ndarray, blur: float, noise: float,
                    jpeg_quality: int | None, rng: np.random.Generator) -> np.ndarray:
    """Lens (distortion), optics blur, sensor noise, 8-bit quantisation, JPEG."""
    img = cv2.remap(ideal, sensor_map[..., 0], sensor_map[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REFLECT)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    img = img * 255.0
    if noise > 0:
        img = img + rng.normal(0.0, noise, img.shape).astype(np.float32)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


# --------------------------------------------------------------------------- the bed


class _Bed:
    """A random dense packing of the wall-layer sphere centres; it shears, types persist.

    Monodisperse spheres against a flat wall are not a perfect crystal: the
    centres form a jammed, mostly disordered disk packing (hexagonal patches,
    rows only next to the bottom plate and the lid, which order the grains
    touching them). It is made by placing the spheres at random and pushing
    overlapping pairs apart (a few hundred relaxation sweeps, walls at the
    lid and plate, periodic along the ring). Each frame every sphere moves
    sideways with the wall-adjacent velocity profile at its height, and a few
    relaxation sweeps remove the overlaps the shear created, so neighbours
    rearrange a little, as in a sheared bed.
    """

    def __init__(self, win, d, n_layers, box, heavy_look, light_look, rng):
        self.win, self.d, self.n_layers = win, d, n_layers
        ox, _, cw, _ = box
        self.x_lo, self.length = ox - d, cw + 2 * d
        spread = max(heavy_look["size_spread"], light_look["size_spread"])
        height = win[3] - win[1]
        count = int(round(PACKING_FRACTION * self.length * height / (np.pi * d * d / 4)))
        self.diam = d * np.clip(rng.normal(1.0, spread, count), 1 - 3 * spread, 1 + 3 * spread)
        self.x0 = rng.uniform(0, self.length, count)
        self.y = rng.uniform(win[1] + self.diam / 2, win[3] - self.diam / 2)
        self._relax(RELAX_SWEEPS, rng, shake=True)
        self.heavy = np.zeros(count, dtype=bool)
        self.shade = rng.normal(1.0, 0.035, count)
        self.rng = rng

    @property
    def layer(self) -> np.ndarray:
        frac = (self.win[3] - self.y) / (self.win[3] - self.win[1]) * self.n_layers
        return np.clip(np.floor(frac).astype(int), 0, self.n_layers - 1)

    def _relax(self, sweeps: int, rng, shake: bool = False, mobility: np.ndarray | None = None) -> None:
        """Push overlapping spheres apart until no pair overlaps by more than 0.2 % of d.

        ``mobility`` (per sphere, > 0) shares each push: the more mobile sphere
        of a pair gives way (sheared grains yield to the still ones above).
        """
        from scipy.spatial import cKDTree

        r = self.diam / 2
        y_lo, y_hi = self.win[1] + r, self.win[3] - r
        box = (self.length, 4 * (self.win[3] - self.win[1]) + 4 * self.d)
        pairs = None
        for sweep in range(sweeps):
            if sweep % 10 == 0:  # neighbour list with a skin, rebuilt every 10 sweeps
                pts = np.column_stack([self.x0 % self.length, self.y - self.win[1] + self.d])
                pairs = cKDTree(pts, boxsize=box).query_pairs(1.3 * self.diam.max(), output_type="ndarray").T
            i, j = pairs
            dx = self.x0[j] - self.x0[i]
            dx -= self.length * np.rint(dx / self.length)
            dy = self.y[j] - self.y[i]
            dist = np.hypot(dx, dy)
            overlap = r[i] + r[j] - dist
            hit = overlap > 0.002 * self.d
            if not hit.any():
                break
            i, j, dx, dy, dist, overlap = i[hit], j[hit], dx[hit], dy[hit], dist[hit], overlap[hit]
            dist = np.maximum(dist, 1e-6)
            # push each sphere of the pair half the overlap (and a little more, to converge)
            mob = np.ones_like(self.y) if mobility is None else mobility
            share_i = mob[i] / (mob[i] + mob[j])
            ux, uy = dx / dist * 1.1 * overlap, dy / dist * 1.1 * overlap
            mx, my = np.zeros_like(self.x0), np.zeros_like(self.y)
            np.add.at(mx, i, -ux * share_i), np.add.at(mx, j, ux * (1 - share_i))
            np.add.at(my, i, -uy * share_i), np.add.at(my, j, uy * (1 - share_i))
            if shake and sweep < sweeps // 2:  # shake early on, so the packing does not lock into a crystal
                mx += rng.normal(0, 0.01 * self.d, mx.size)
                my += rng.normal(0, 0.01 * self.d, my.size)
            self.x0 = (self.x0 + mx) % self.length
            self.y = np.clip(self.y + my, y_lo, y_hi)

    def positions(self, frame: int, shift: float, delta_over_H: float) -> np.ndarray:
        """x [undistorted px] of every sphere at ``frame`` (frames come in order; the bed shears)."""
        if frame > 0:
            height = self.win[3] - self.win[1]
            profile = np.exp(-(self.win[3] - self.y) / (delta_over_H * height))
            before = self.x0 + shift * profile
            self.x0 = before % self.length
            for _ in range(3):
                # grains make room for each other, but each height keeps its mean speed
                self._relax(SHEAR_SWEEPS, self.rng, mobility=profile + 1e-3)
                moved = (self.x0 - before + self.length / 2) % self.length - self.length / 2
                band = np.clip(((self.y - self.win[1]) / (0.5 * self.d)).astype(int), 0, None)
                mean = np.bincount(band, moved) / np.maximum(np.bincount(band), 1)
                self.x0 = (self.x0 - mean[band]) % self.length
            self._relax(SHEAR_SWEEPS, self.rng, mobility=profile + 1e-3)
        return self.x_lo + self.x0

    def in_window(self, x: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.win
        return (x >= x0) & (x < x1) & (self.y >= y0) & (self.y < y1)

    def assign_types(self, x: np.ndarray, c_row: np.ndarray, rng) -> None:
        """Flip as few spheres as possible so each layer's heavy share is c_row."""
        inside = self.in_window(x)
        layer = self.layer
        for j in range(self.n_layers):
            for group in (inside, ~inside):
                idx = np.flatnonzero(group & (layer == j))
                target = int(np.rint(c_row[j] * idx.size))
                self._flip(idx, target, rng)

    def _flip(self, idx: np.ndarray, target: int, rng) -> None:
        is_heavy = self.heavy[idx]
        excess = int(is_heavy.sum()) - target
        pool = idx[is_heavy] if excess > 0 else idx[~is_heavy]
        if excess != 0:
            self.heavy[rng.choice(pool, abs(excess), replace=False)] = excess < 0

    def layer_counts(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        inside = self.in_window(x)
        layer = self.layer
        n = np.bincount(layer[inside], minlength=self.n_layers)
        nh = np.bincount(layer[inside & self.heavy], minlength=self.n_layers)
        return n, nh

    def truth(self, x: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.win
        near = (x >= x0 - self.d) & (x < x1 + self.d) & (self.y >= y0 - self.d) & (self.y < y1 + self.d)
        cols = [x, self.y, self.diam, self.heavy, self.in_window(x)]
        return np.stack([np.asarray(v, dtype=float)[near] for v in cols], axis=1)


# --------------------------------------------------------------------------- drawing


class _Scene:
    """Draws the ideal (undistorted, noise-free) image of the wall, float BGR in [0, 1]."""

    def __init__(self, box, win, d, heavy_look, light_look, lighting, rng):
        if lighting not in LIGHTINGS:
            raise ValueError(f"lighting must be one of {sorted(LIGHTINGS)}, got {lighting!r}")
        self.ox, self.oy, self.cw, self.ch = box
        self.win, self.d = win, d
        self.looks = (light_look, heavy_look)
        self.lights = LIGHTINGS[lighting]
        self.behind = self._behind(heavy_look, light_look, rng)
        self.base = self._walls()

    def _behind(self, heavy_look, light_look, rng) -> np.ndarray:
        """What is seen through gaps and glass: darker, blurred grains further in."""
        cell = max(self.d / 2.5, 2.0)
        small = (max(int(self.ch / cell), 2), max(int(self.cw / cell), 2))
        mix = rng.uniform(0, 1, small)
        mix = np.clip(cv2.resize(mix, (self.cw, self.ch), interpolation=cv2.INTER_CUBIC), 0, 1)
        cols = [np.array(look["colour"]) for look in (light_look, heavy_look)]
        img = (1 - mix[..., None]) * cols[0] + mix[..., None] * cols[1]
        return (0.06 + 0.3 * img * mix[..., None] ** 0.5).astype(np.float32)

    def _walls(self) -> np.ndarray:
        """Dark gaps in the bed; the lid above and the plate below are grey metal."""
        img = self.behind * 0.3  # gaps between wall-touching spheres are in shadow
        yy = np.arange(self.ch) + self.oy
        lid = yy < self.win[1]
        plate = yy >= self.win[3]
        img[lid] = np.array([0.30, 0.29, 0.28], np.float32)
        img[plate] = np.array([0.22, 0.22, 0.24], np.float32)
        edge = np.abs(yy - self.win[3]) < 2
        img[edge] = 0.45
        return img

    def draw(self, x: np.ndarray, bed: _Bed, exposure: float, vignetting: float) -> np.ndarray:
        img = self.base.copy()
        cx, cy = x - self.ox, bed.y - self.oy
        r = bed.diam / 2
        keep = (cx > -self.d) & (cx < self.cw + self.d)
        for idx in np.array_split(np.flatnonzero(keep), max(1, keep.sum() // 400)):
            self._draw_batch(img, cx[idx], cy[idx], r[idx], bed.heavy[idx], bed.shade[idx])
        return self._illumination(img, exposure, vignetting)

    def _draw_batch(self, img, cx, cy, r, heavy, shade) -> None:
        s = int(np.ceil(2 * r.max())) + 4
        bx, by = np.floor(cx - s / 2).astype(int), np.floor(cy - s / 2).astype(int)
        g = np.arange(s, dtype=np.float32)
        dx = (bx[:, None, None] + g[None, None, :]) - cx[:, None, None]
        dy = (by[:, None, None] + g[None, :, None]) - cy[:, None, None]
        dx, dy = np.broadcast_arrays(dx, dy)
        dist = np.sqrt(dx * dx + dy * dy)
        alpha = np.clip(r[:, None, None] - dist + 0.5, 0, 1).astype(np.float32)
        colour = np.empty((*dx.shape, 3), np.float32)
        for kind in (0, 1):
            sel = heavy == kind
            if sel.any():
                colour[sel] = self._shade(dx[sel], dy[sel], r[sel], cx[sel], cy[sel], self.looks[kind])
        colour *= shade[:, None, None, None].astype(np.float32)
        for k in np.random.default_rng(len(cx)).permutation(len(cx)):
            _paste(img, colour[k], alpha[k], bx[k], by[k])

    def _shade(self, dx, dy, r, cx, cy, look) -> np.ndarray:
        """Per-pixel colour of spheres of one material, (m, s, s, 3)."""
        rr = r[:, None, None]
        nx, ny = np.clip(dx / rr, -1, 1), np.clip(dy / rr, -1, 1)
        nz = np.sqrt(np.clip(1 - nx * nx - ny * ny, 0, 1))
        diffuse, spec = np.zeros_like(nx), np.zeros_like(nx)
        for lx, ly, lz, power in self.lights:
            ln = np.array([lx, ly, lz]) / np.linalg.norm([lx, ly, lz])
            hv = ln + np.array([0, 0, 1.0])
            hv /= np.linalg.norm(hv)
            diffuse += power * np.clip(nx * ln[0] + ny * ln[1] + nz * ln[2], 0, None)
            ndoth = np.clip(nx * hv[0] + ny * hv[1] + nz * hv[2], 0, None)
            spec += power * ndoth ** look["shininess"]
        base = np.array(look["colour"], np.float32)
        rim = 1 - nz
        if look["metal"]:
            env = self._environment(nx, ny, nz)
            body = base * (0.25 + 0.75 * env[..., None]) * (1 - 0.55 * rim[..., None] ** 2)
        elif look["glass"]:
            body = self._glass(dx, dy, cx, cy, rim, base)
        else:
            body = base * (0.18 + look["kd"] * diffuse[..., None]) * (1 - 0.45 * rim[..., None] ** 3)
        return (body + look["ks"] * spec[..., None]).astype(np.float32)

    def _environment(self, nx, ny, nz) -> np.ndarray:
        """Brightness of the surroundings mirrored by a metal sphere."""
        ry = 2 * nz * ny  # reflected ray, y component (down positive)
        sky = 0.8 * np.clip(0.5 - 0.5 * ry, 0, 1) ** 1.5
        lamps = np.zeros_like(nx)
        for lx, ly, lz, power in self.lights:
            ln = np.array([lx, ly, lz]) / np.linalg.norm([lx, ly, lz])
            rdotl = 2 * nz * (nx * ln[0] + ny * ln[1] + nz * ln[2]) - ln[2]
            lamps += power * 0.9 * np.exp(-(1 - rdotl) / 0.05)
        return 0.15 + sky + lamps

    def _glass(self, dx, dy, cx, cy, rim, tint) -> np.ndarray:
        """Transparent sphere: the grains behind, inverted and tinted; dark outline."""
        mx = (cx[:, None, None] - 0.55 * dx).astype(np.float32)
        my = (cy[:, None, None] - 0.55 * dy).astype(np.float32)
        m, s = dx.shape[0], dx.shape[1]
        seen = cv2.remap(self.behind, mx.reshape(m * s, s), my.reshape(m * s, s),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).reshape(m, s, s, 3)
        ring = np.clip((rim - 0.45) / 0.35, 0, 1)
        body = (0.22 + 1.8 * seen) * tint * (1 - 0.85 * ring[..., None])
        return body + 0.25 * np.exp(-((rim - 0.93) / 0.05) ** 2)[..., None]

    def _illumination(self, img: np.ndarray, exposure: float, vignetting: float) -> np.ndarray:
        """Lamps at the sides and lens vignetting: smooth brightness over the image."""
        yy, xx = np.mgrid[0:self.ch, 0:self.cw].astype(np.float32)
        u = (xx - self.cw / 2) / (self.cw / 2)
        v = (yy - self.ch / 2) / (self.ch / 2)
        gain = exposure * (1 - vignetting * (u * u + v * v) / 2)
        return np.clip(img * gain[..., None], 0, 1.2).astype(np.float32)


def _paste(img: np.ndarray, colour: np.ndarray, alpha: np.ndarray, x: int, y: int) -> None:
    """Alpha-blend one sprite at (x, y), clipped to the canvas."""
    h, w = img.shape[:2]
    s = alpha.shape[0]
    x_a, y_a, x_b, y_b = max(x, 0), max(y, 0), min(x + s, w), min(y + s, h)
    if x_a >= x_b or y_a >= y_b:
        return
    a = alpha[y_a - y:y_b - y, x_a - x:x_b - x, None]
    region = img[y_a:y_b, x_a:x_b]
    region *= 1 - a
    region += a * colour[y_a - y:y_b - y, x_a - x:x_b - x]


# --------------------------------------------------------------------------- output


def _experiment(heavy, light, cmap, k_mat, dist, win, d, fps, extra) -> dict[str, Any]:
    rho = _densities(heavy, light)
    meta = {
        "name": f"synthetic-{heavy}-{light}",
        "heavy": heavy, "light": light,
        "rho_h": rho[0], "rho_l": rho[1],
        "c0": float(np.clip(cmap[0].mean(), 0.01, 0.99)),
        "M_g": 2.0, "M_w": 1.093,
        "fps": float(fps),
        "camera_matrix": np.asarray(k_mat).tolist(),
        "dist_coeffs": np.asarray(dist).tolist(),
        "window": [float(v) for v in win],
        "particle_diameter_px": float(d),
    }
    meta.update(extra or {})
    return meta


def _densities(heavy: str, light: str) -> tuple[float, float]:
    """Solid densities [kg/m^3] of the two materials, from the model's table."""
    try:
        from granseg.model import MATERIALS

        table = {k.lower(): float(v) for k, v in MATERIALS.items()}
        return table[heavy.lower()], table[light.lower()]
    except (ImportError, KeyError, AttributeError):
        # The model (Rust extension) is not available: nominal placeholders,
        # heavier first. Pass experiment={"rho_h": ..., "rho_l": ...} to set them.
        return 2.0e3, 1.0e3


def _write(result: RenderedFrames, out: Path, jpeg_quality: int | None, force: bool) -> list[Path]:
    from granseg._io import atomic_path, save_json

    out.mkdir(parents=True, exist_ok=True)
    ext = ".png" if jpeg_quality is None else ".jpg"
    params = [] if jpeg_quality is None else [cv2.IMWRITE_JPEG_QUALITY, 100]
    paths = []
    for i, img in enumerate(result.images):
        p = out / f"frame_{i:04d}{ext}"
        with atomic_path(p, force=force) as tmp:
            if not cv2.imwrite(str(tmp), img, params):
                raise OSError(f"{p}: could not write image")
        paths.append(p)
    paths.append(save_json(out / "experiment.json", result.experiment, force=force))
    return paths


# --------------------------------------------------------------------------- checkerboard


def render_checkerboard(
    camera_matrix: Any,
    dist_coeffs: Any,
    image_size: tuple[int, int],
    rvec: Any,
    tvec: Any,
    pattern: tuple[int, int] = (9, 6),
    square: float = 1.0,
    supersample: int = 2,
) -> np.ndarray:
    """A checkerboard photographed by the given camera, as a grey uint8 image.

    The board has ``pattern`` = (columns, rows) inner corners, squares of side
    ``square`` (any length unit, the unit of ``tvec``), and a one-square white
    border; it lies in the plane Z = 0 of the board frame, posed by the
    Rodrigues vector ``rvec`` and translation ``tvec``. ``image_size`` is
    (width, height) [px]. Each sensor pixel looks along its undistorted ray,
    so the image carries the lens distortion exactly.
    """
    k = np.asarray(camera_matrix, dtype=float).reshape(3, 3)
    dist = np.asarray(dist_coeffs, dtype=float).ravel()
    w, h = image_size
    ss = int(supersample)
    xs, ys = np.meshgrid((np.arange(w * ss) + 0.5) / ss - 0.5, (np.arange(h * ss) + 0.5) / ss - 0.5)
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)
    ray = cv2.undistortPoints(pts, k, dist, criteria=crit).reshape(-1, 2)
    rot, _ = cv2.Rodrigues(np.asarray(rvec, dtype=float))
    t = np.asarray(tvec, dtype=float).ravel()
    # Intersect the ray (x, y, 1) * s with the board plane n . (P - t) = 0.
    normal = rot[:, 2]
    dirs = np.concatenate([ray, np.ones((ray.shape[0], 1))], axis=1)
    s = (normal @ t) / (dirs @ normal)
    board = (dirs * s[:, None] - t) @ rot  # board coordinates
    u, v = board[:, 0] / square, board[:, 1] / square
    cols, rows = pattern
    inside = (u > -1) & (u < cols + 1) & (v > -1) & (v < rows + 1) & (s > 0)
    dark = ((np.floor(u) + np.floor(v)) % 2 == 0) & (u > 0) & (u < cols + 1) & (v > 0) & (v < rows + 1)
    # squares are offset so that inner corners sit at integer (u, v) = 1..cols
    val = np.where(inside, np.where(dark, 30.0, 225.0), 120.0).reshape(h * ss, w * ss)
    img = cv2.resize(val, (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
