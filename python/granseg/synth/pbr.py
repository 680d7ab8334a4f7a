"""Physically based side-wall frames of the shear cell (Mitsuba 3), with exact ground truth.

A second look for the tests, independent of :mod:`granseg.synth.frames`:
:func:`render_pbr_frames` path-traces 6 mm spheres of real materials (rough
conducting steel, white ceramic, slightly green rough glass, dark filled POM,
blue polypropylene; or a matte and a glossy grey plastic) packed against the
inside of the outer PMMA cylinder of the cell (inner radius D_out / 2 of
docs/model.md, 5 mm thick, IOR 1.49), a second, partly hidden layer behind them,
the 3-D-printed PLA lid and plate (the paper's material) with hemispherical
bumps one diameter across, two LED panel lamps beside the camera and a dark
interior. A pinhole camera looks through the curved wall; the OpenCV lens
distortion, vignetting, shot and read noise, the sRGB curve and JPEG are
applied afterwards, so the ``camera_matrix`` and ``dist_coeffs`` of
``experiment.json`` describe the footage exactly.

The wall is part of the camera (``_wall_camera_class``): every camera ray is
refracted at both cylinder surfaces by Snell's law or, with the Fresnel
probability, reflected by the outer one (the lamps' glare). As a shape of
the scene a smooth dielectric shell would hide the lamps from next-event
estimation and leave the grains lit only by paths that happen to hit a lamp
(hopelessly noisy); the light reaching the grains through the wall is only
slightly attenuated and bent, which the renderer ignores. The fixtures
command checks the wall camera against Mitsuba's own ``dielectric``
cylinders (``verification.json``).

The wall-layer centres come from the 2-D packing of ``frames._Bed`` (arc
length along the wall, height above the plate), sheared frame by frame and
typed to follow the map ``c`` as :func:`granseg.synth.render_frames` does;
bumps of the plate turn with it and take the place of the grains they
overlap. The truth is the *apparent* centre of each sphere in undistorted
pixels: the centroid of its outline seen through the refracting wall, traced
analytically; the fixtures command checks it against masks that Mitsuba
renders through the dielectric shell.

Layers. The window's y0 / y1 are the images of sphere centres 15 D and 0 D
above the plate in the column facing the camera, its x0 / x1 those of
centres +-4.5 D along the wall at mid-height; the camera sits at mid-height.
``n`` / ``n_heavy`` count spheres by their apparent centre in the window,
like ``render_frames`` (what a perfect detector finds); away from the centre
column perspective makes a sphere look up to ~0.2 D closer to mid-height
than it is, so ``n_phys`` / ``n_heavy_phys`` also count by the true height
above the plate (layer j: centre in [j, j + 1) D) and the true arc position.

mitsuba is optional (``pip install mitsuba``); only :func:`render_pbr_frames`
imports it (with Dr.Jit's LLVM back end when a libLLVM >= 17 is installed,
else the slower scalar variant). :func:`load_fixture` needs only NumPy and
OpenCV.

Render the committed test fixtures (``tests/fixtures/pbr``; 2 to 4 minutes
per look on two shared cores, LLVM back end) with::

    python -m granseg.synth.pbr fixtures tests/fixtures/pbr [--force] [--looks glass-pom,...] [--spp N]

and the tuning family (other packings of the same looks, seeds + 100, never
committed: what a detector change may be developed on) with::

    python -m granseg.synth.pbr fixtures /tmp/pbr-tune --seed-offset 100 --no-verify
"""

from __future__ import annotations

import argparse
import glob
import json
import logging
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from granseg._io import atomic_path, atomic_write, save_json
from granseg.synth.frames import MATERIAL_LOOKS, RenderedFrames, _Bed, _check_map
from granseg.synth.frames import _experiment as frame_experiment

log = logging.getLogger(__name__)

__all__ = ["FIXTURE_LOOKS", "PBR_MATERIALS", "PbrFrames", "fixture_map", "load_fixture", "render_fixtures",
           "render_pbr_frames"]

# --------------------------------------------------------------------------- the cell [mm]

D_MM = 6.0  # sphere diameter (docs/model.md D_p)
R_WALL = 95.0  # inner radius of the outer PMMA cylinder (docs/model.md D_out / 2)
WALL_MM = 5.0  # thickness of the PMMA wall
PMMA_IOR = 1.49
PLATE_GAP = 0.5  # radial gap between the plate / lid and the wall
TOUCH_GAP = 0.02  # grains "touching" the wall keep this gap [mm] (the camera rays start on the wall)
SECOND_LAYER = 0.9 * D_MM  # the second layer's centres lie this much further in
GLARE_SHARE = 0.2  # share of camera samples spent on the wall's reflection
BUMP_SPACING = 3.0 * D_MM  # hemispheres D across, ~2 D between their edges (paper)
BUMP_SETBACK = 0.25 * D_MM  # the bumps nearest the wall stay this far from it (beyond the plate's gap)
BUMP_OVERLAP = 0.15 * D_MM  # a grain overlapping a bump by more is left out (less: hidden behind it)

# Mitsuba BSDFs of the materials (linear RGB). size_spread: relative standard
# deviation of the diameter (as MATERIAL_LOOKS); "diffuse" entries get a few
# per-sphere shades.
PBR_MATERIALS: dict[str, dict[str, Any]] = {
    # stainless steel: Fe optical constants (n, k at R, G, B), polished
    "steel": dict(bsdf={"type": "roughconductor", "alpha": 0.04,
                        "eta": {"type": "rgb", "value": [2.87, 2.95, 2.65]},
                        "k": {"type": "rgb", "value": [3.08, 2.93, 2.81]}},
                  size_spread=0.004),
    "ceramic": dict(bsdf={"type": "roughplastic", "alpha": 0.3, "int_ior": 1.6,
                          "diffuse_reflectance": {"type": "rgb", "value": [0.78, 0.77, 0.73]}},
                    size_spread=0.035),
    "glass": dict(bsdf={"type": "roughdielectric", "alpha": 0.02, "int_ior": 1.52, "ext_ior": 1.0,
                        "specular_transmittance": {"type": "rgb", "value": [0.92, 0.98, 0.93]}},
                  size_spread=0.02),
    "pom": dict(bsdf={"type": "roughplastic", "alpha": 0.15, "int_ior": 1.48,
                      "diffuse_reflectance": {"type": "rgb", "value": [0.045, 0.045, 0.05]}},
                size_spread=0.01),
    "pp": dict(bsdf={"type": "roughplastic", "alpha": 0.08, "int_ior": 1.49,
                     "diffuse_reflectance": {"type": "rgb", "value": [0.03, 0.09, 0.50]}},
               size_spread=0.008),
    # a pair that differs in gloss only: same grey, one matte, one polished
    "grey-matte": dict(bsdf={"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.22, 0.22, 0.22]}},
                       size_spread=0.01),
    "grey-glossy": dict(bsdf={"type": "plastic", "int_ior": 1.5,
                              "diffuse_reflectance": {"type": "rgb", "value": [0.22, 0.22, 0.22]}},
                        size_spread=0.01),
}

PLA = {"type": "roughplastic", "alpha": 0.35, "int_ior": 1.46,
       "diffuse_reflectance": {"type": "rgb", "value": [0.30, 0.30, 0.29]}}

# LED panels beside the camera at mid-height, facing the window: (azimuth from the
# camera's direction [deg], distance from the cell's axis [mm]); size [mm]
LAMPS: dict[str, list[tuple[float, float]]] = {
    "two-sided": [(-55.0, 270.0), (55.0, 270.0)],
    "left": [(-55.0, 270.0)],
    # one panel straight behind the camera: the curved wall mirrors it in a
    # bright band down the middle of the window
    "front": [(0.0, 300.0)],
}
LAMP_SIZE = (60.0, 200.0)

# The fixture set: name -> render_pbr_frames arguments (see the module docstring).
# The paper's six pairs (M_g from its Table 1), the four other pairs of its five
# materials (M_g as Table 1 gives it for every run: 1.2e-3 m^3 of solid times the
# mean solid density) and a pair that differs in gloss only.
FIXTURE_LOOKS: dict[str, dict[str, Any]] = {
    "glass-pom": dict(heavy="glass", light="pom", c0=0.5, seed=11, experiment={"M_g": 2.52}),
    "steel-pom": dict(heavy="steel", light="pom", c0=0.25, seed=12, experiment={"M_g": 3.92}),
    "ceramic-pp": dict(heavy="ceramic", light="pp", c0=0.5, seed=13, experiment={"M_g": 2.67}),
    "steel-pp": dict(heavy="steel", light="pp", c0=0.5, seed=14, experiment={"M_g": 5.25}),
    "glass-pp": dict(heavy="glass", light="pp", c0=0.5, seed=15, experiment={"M_g": 2.04}),
    "pom-pp": dict(heavy="pom", light="pp", c0=0.5, seed=16, experiment={"M_g": 1.62}),
    "steel-glass": dict(heavy="steel", light="glass", c0=0.5, seed=18, experiment={"M_g": 6.15}),
    "steel-ceramic": dict(heavy="steel", light="ceramic", c0=0.75, seed=19, experiment={"M_g": 8.07}),
    "ceramic-glass": dict(heavy="ceramic", light="glass", c0=0.5, seed=20, experiment={"M_g": 3.57}),
    "ceramic-pom": dict(heavy="ceramic", light="pom", c0=0.25, seed=21, experiment={"M_g": 2.63}),
    "grey-glossy-matte": dict(heavy="grey-glossy", light="grey-matte", c0=0.5, seed=17,
                              experiment={"rho_h": 2000.0, "rho_l": 1000.0, "M_g": 2.0}),
    # the pom-pp pair under a panel behind the camera instead of the two side panels
    "pom-pp-front": dict(heavy="pom", light="pp", c0=0.5, seed=22, lighting="front", experiment={"M_g": 1.62}),
}
FIXTURE_FRAMES = 4
FIXTURE_SIZE = (640, 720)
FIXTURE_D_PX = 34.0
FIXTURE_SPP = 128
FIXTURE_JPEG = 88
FIXTURE_NOISE = 0.7
# Packings of the fixture looks rendered with seed + TUNING_SEED_OFFSET are
# the physically based tuning family (never committed, never in a test): the
# detector may be developed on them, and is judged on the fixtures.
TUNING_SEED_OFFSET = 100


@dataclass
class PbrFrames(RenderedFrames):
    """:class:`RenderedFrames` plus what only a 3-D scene has.

    height: per frame, (m,) true height of each listed sphere's centre above
        the plate [D] (rows as ``particles``).
    n_phys, n_heavy_phys: (n_t, n_layers) counts by true height (layer j:
        [j, j + 1) D) and true position along the wall (within +-4.5 D of the
        centre column).
    bumps: (k, 4) frame, x, y [undistorted px], lid (1) / plate (0): the
        apparent base centres of the hemispheres near the wall.
    c: the map rendered, (n_t, n_layers).
    centres: per frame, (m, 4) the 3-D centre [mm] and radius [mm] of each
        listed sphere (world frame of the module docstring).
    encoded: the frame files' bytes (as rendered; empty when loaded).
    """

    height: list[np.ndarray] = field(default_factory=list)
    n_phys: np.ndarray | None = None
    n_heavy_phys: np.ndarray | None = None
    bumps: np.ndarray | None = None
    c: np.ndarray | None = None
    centres: list[np.ndarray] = field(default_factory=list)
    encoded: list[bytes] = field(default_factory=list, repr=False)


# --------------------------------------------------------------------------- geometry


def _hit_cylinder(o: np.ndarray, d: np.ndarray, radius: float) -> np.ndarray:
    """First intersection parameter of rays o + t d with the vertical cylinder x^2 + z^2 = R^2."""
    a = d[..., 0] ** 2 + d[..., 2] ** 2
    b = 2 * (o[..., 0] * d[..., 0] + o[..., 2] * d[..., 2])
    c = o[..., 0] ** 2 + o[..., 2] ** 2 - radius**2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        return (-b - np.sqrt(disc)) / (2 * a)


def _refract(d: np.ndarray, n: np.ndarray, eta: float) -> np.ndarray:
    """Snell's law: direction d through a surface of normal n (facing d), eta = n1 / n2."""
    cos_i = -np.sum(n * d, axis=-1, keepdims=True)
    k = 1 - eta**2 * (1 - cos_i**2)
    with np.errstate(invalid="ignore"):
        return eta * d + (eta * cos_i - np.sqrt(k)) * n


class _Cell:
    """The camera, the curved wall and the maps between the bed, 3-D space and pixels.

    World [mm]: y up, the cell's axis is the y axis, the plate surface is y = 0,
    the camera sits at (0, y_cam, z_cam) looking along -z; a point at angle
    theta (towards +x) and radius rho is (rho sin theta, y, rho cos theta).
    """

    def __init__(self, k_mat: np.ndarray, d_px: float, n_layers: int):
        self.fx, self.fy = float(k_mat[0, 0]), float(k_mat[1, 1])
        self.cx, self.cy = float(k_mat[0, 2]), float(k_mat[1, 2])
        if abs(self.fx - self.fy) > 1e-6 * self.fx or abs(k_mat[0, 1]) > 1e-9:
            raise ValueError("render_pbr_frames needs square pixels (fx == fy, no skew)")
        self.d_px, self.n_layers = float(d_px), int(n_layers)
        self.height = n_layers * D_MM
        self.y_cam = self.height / 2
        self.rho1 = R_WALL - D_MM / 2 - TOUCH_GAP  # centres of nominal spheres touching the wall
        self.rho2 = self.rho1 - SECOND_LAYER
        self.z_cam = self._solve_distance()

    # rays ------------------------------------------------------------------

    def rays(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origin and direction of the rays of undistorted pixels (u, v) inside the cell."""
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        d = np.stack([(u - self.cx) / self.fx, -(v - self.cy) / self.fy, -np.ones_like(u)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(np.array([0.0, self.y_cam, self.z_cam]), d.shape)
        for radius, eta in ((R_WALL + WALL_MM, 1 / PMMA_IOR), (R_WALL, PMMA_IOR)):
            p = o + _hit_cylinder(o, d, radius)[..., None] * d
            n = p * np.array([1.0, 0.0, 1.0]) / radius  # outward normal, faces the inward ray
            d = _refract(d, n, eta)
            o = p
        return o, d

    def project(self, pts: np.ndarray) -> np.ndarray:
        """Undistorted pixel whose ray passes through each 3-D point (n, 3) -> (n, 2)."""
        pts = np.atleast_2d(np.asarray(pts, float))
        depth = self.z_cam - pts[:, 2]
        uv = np.stack([self.cx + self.fx * pts[:, 0] / depth,
                       self.cy - self.fy * (pts[:, 1] - self.y_cam) / depth], axis=1)

        def miss(uv):
            o, d = self.rays(uv[:, 0], uv[:, 1])
            t = (pts[:, 2] - o[:, 2]) / d[:, 2]
            return (o + t[:, None] * d)[:, :2] - pts[:, :2]

        h = 0.25
        for _ in range(12):
            f0 = miss(uv)
            jx = (miss(uv + [h, 0]) - f0) / h
            jy = (miss(uv + [0, h]) - f0) / h
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            du = (f0[:, 0] * jy[:, 1] - jy[:, 0] * f0[:, 1]) / det
            dv = (jx[:, 0] * f0[:, 1] - f0[:, 0] * jx[:, 1]) / det
            uv = uv - np.stack([du, dv], axis=1)
            if np.nanmax(np.abs(np.concatenate([du, dv]))) < 1e-7:
                break
        return uv

    def outline(self, centres: np.ndarray, radii: np.ndarray, n_dir: int = 32
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Apparent outline of spheres: its area centroid (n, 2), equivalent diameter (n,) [px]
        and the projected centre (n, 2), all in undistorted pixels."""
        centres = np.atleast_2d(np.asarray(centres, float))
        radii = np.asarray(radii, float)
        proj = self.project(centres)
        phi = np.arange(n_dir) * 2 * np.pi / n_dir
        cs, sn = np.cos(phi), np.sin(phi)
        lo = np.zeros((len(centres), n_dir))
        hi = np.full_like(lo, 1.2 * self.d_px) * (radii[:, None] / (D_MM / 2))
        for _ in range(40):  # bisection: inside while the ray passes closer than r to the centre
            mid = (lo + hi) / 2
            o, d = self.rays(proj[:, 0, None] + mid * cs, proj[:, 1, None] + mid * sn)
            rel = centres[:, None, :] - o
            along = np.sum(rel * d, axis=-1, keepdims=True)
            dist = np.linalg.norm(rel - along * d, axis=-1)
            inside = dist < radii[:, None]
            lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
        rad = (lo + hi) / 2
        px, py = proj[:, 0, None] + rad * cs, proj[:, 1, None] + rad * sn
        qx, qy = np.roll(px, -1, axis=1), np.roll(py, -1, axis=1)
        cross = px * qy - qx * py
        area = cross.sum(axis=1) / 2
        cx = ((px + qx) * cross).sum(axis=1) / (6 * area)
        cy = ((py + qy) * cross).sum(axis=1) / (6 * area)
        area *= (2 * np.pi / n_dir) / np.sin(2 * np.pi / n_dir)  # the outline, not the inscribed polygon
        return np.stack([cx, cy], axis=1), np.sqrt(4 * np.abs(area) / np.pi), proj

    def _solve_distance(self) -> float:
        """Camera distance at which a wall sphere facing the camera is d_px across."""
        centre = np.array([[0.0, self.y_cam, self.rho1]])
        z = self.rho1 + self.fx * D_MM / self.d_px
        sizes = []
        for _ in range(30):
            self.z_cam = z
            size = self.outline(centre, np.array([D_MM / 2]))[1][0]
            sizes.append((z, size))
            if abs(size - self.d_px) < 1e-6:
                break
            if len(sizes) == 1:
                z_new = z * (1 + 0.02 * np.sign(size - self.d_px))
            else:
                (z0, s0), (z1, s1) = sizes[-2], sizes[-1]
                z_new = z1 - (s1 - self.d_px) * (z1 - z0) / (s1 - s0)
            z = z_new
        return float(z)

    # the bed ----------------------------------------------------------------

    def point(self, arc_px: np.ndarray, y_px: np.ndarray, rho_arc: float, rho: Any) -> np.ndarray:
        """3-D point of bed coordinates (arc length along the cylinder of radius rho_arc, y as in
        _Bed: 0 = lid) [px], placed at radius rho [mm] (a number or one per point)."""
        theta = np.asarray(arc_px) / self.d_px * D_MM / rho_arc
        h = (self.n_layers * self.d_px - np.asarray(y_px)) / self.d_px * D_MM
        return np.stack([rho * np.sin(theta), h, rho * np.cos(theta)], axis=-1)

    def window(self) -> np.ndarray:
        """(x0, y0, x1, y1): centres +-4.5 D along the wall at mid-height, 15 D and 0 D high below the camera."""
        half = 4.5 * D_MM / self.rho1
        pts = np.array([[-self.rho1 * np.sin(half), self.y_cam, self.rho1 * np.cos(half)],
                        [self.rho1 * np.sin(half), self.y_cam, self.rho1 * np.cos(half)],
                        [0.0, self.height, self.rho1], [0.0, 0.0, self.rho1]])
        uv = self.project(pts)
        return np.array([uv[0, 0], uv[2, 1], uv[1, 0], uv[3, 1]])

    def visible_arc(self, canvas: tuple[float, float, int, int], rho: float) -> float:
        """Half-length [bed px] of the arc at radius rho that the canvas sees, plus a margin."""
        ox, oy, cw, ch = canvas
        u = np.array([ox, ox + cw, ox, ox + cw, ox, ox + cw])
        v = np.array([oy, oy, oy + ch, oy + ch, oy + ch / 2, oy + ch / 2])
        o, d = self.rays(u, v)
        t = _hit_cylinder(o, d, self.rho1)
        p = o + t[:, None] * d
        theta = np.abs(np.arctan2(p[:, 0], p[:, 2]))
        # rays that miss the wall layer graze it: it is seen up to its tangent
        theta = np.nanmax(np.where(np.isfinite(theta), theta, np.pi / 2))
        if rho < self.rho1:
            theta += 0.3  # layers further in are seen through gaps at steeper angles
        return (min(theta, np.pi / 2) * rho / D_MM + 2.0) * self.d_px


# --------------------------------------------------------------------------- lens


def _canvas(k_mat: np.ndarray, dist: np.ndarray, size: tuple[int, int]):
    """Undistorted canvas centred on the principal point covering the sensor.

    Returns (sensor map (H, W, 2) float32 in canvas pixels, (ox, oy, cw, ch)):
    canvas pixel (i, j) is undistorted pixel (ox + i, oy + j).
    """
    w, h = size
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)
    und = cv2.undistortPoints(pts, k_mat, dist, P=k_mat, criteria=crit).reshape(h, w, 2)
    if not np.all(np.isfinite(und)):
        raise ValueError("dist_coeffs: distortion too strong to render")
    cx, cy = k_mat[0, 2], k_mat[1, 2]
    cw = 2 * int(np.ceil(max(cx - und[..., 0].min(), und[..., 0].max() - cx) + 3))
    ch = 2 * int(np.ceil(max(cy - und[..., 1].min(), und[..., 1].max() - cy) + 3))
    if cw > 4 * w or ch > 4 * h:
        raise ValueError("dist_coeffs: distortion too strong to render (lens model folds over)")
    ox, oy = cx - cw / 2 + 0.5, cy - ch / 2 + 0.5
    return (und - [ox, oy]).astype(np.float32), (ox, oy, cw, ch)


def _default_camera(size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A normal lens (f = 1.5 x width) with visible barrel distortion, principal point a little off centre."""
    w, h = size
    f = 1.5 * w
    k = np.array([[f, 0.0, (w - 1) / 2 + 3.0], [0.0, f, (h - 1) / 2 - 2.0], [0.0, 0.0, 1.0]])
    k1 = -0.25
    return k, np.array([k1, 0.3 * k1 * k1, 0.0004, -0.0003, 0.0])


# --------------------------------------------------------------------------- mitsuba


# Dr.Jit's LLVM back end in mitsuba 3.9.1 aborts on libLLVM 16 ("Cannot select:
# fmaximum") and works on 19 (measured; 17 and 18 not tried). Older ones fall
# back to the scalar variant, many times slower.
MIN_LLVM = 17


def _find_llvm() -> str | None:
    """A libLLVM new enough (MIN_LLVM) for Dr.Jit's LLVM back end, if one is installed."""
    best: tuple[int, str] | None = None
    pats = ["/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
            "/usr/lib64/libLLVM*.so*", "/opt/homebrew/opt/llvm/lib/libLLVM.dylib"]
    for pat in pats:
        for p in glob.glob(pat):
            m = re.search(r"(?:llvm-|LLVM-|LLVM\.so\.)(\d+)", p)
            if m and int(m.group(1)) >= MIN_LLVM and (best is None or int(m.group(1)) > best[0]):
                best = (int(m.group(1)), p)
    return best[1] if best else None


_REGISTERED: set[str] = set()


def _mitsuba(variant: str | None):
    """Import mitsuba, pick a variant (llvm_ad_rgb if a recent libLLVM is found, else
    scalar_rgb) and register the wall camera."""
    variant = variant or os.environ.get("GRANSEG_MITSUBA_VARIANT")
    if variant is None and "drjit" not in sys.modules and "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = _find_llvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError("render_pbr_frames needs mitsuba: pip install 'mitsuba>=3.9' "
                          "(or granseg[pbr])") from exc
    if variant is None:
        variant = "llvm_ad_rgb" if os.environ.get("DRJIT_LIBLLVM_PATH") else "scalar_rgb"
        if variant == "scalar_rgb" and variant not in _REGISTERED:  # once a process, not per look
            # Said aloud because the fallback is silent otherwise: a 90 s fixture
            # render ran 18 minutes on a machine without a recent libLLVM.
            log.warning("no libLLVM >= %d found: mitsuba renders with its scalar variant, "
                        "about 12x slower (install one, e.g. apt-get install libllvm19, or set "
                        "DRJIT_LIBLLVM_PATH)", MIN_LLVM)
    mi.set_variant(variant)
    if variant not in _REGISTERED:
        cls = _wall_camera_class(mi)
        mi.register_sensor("granseg_wall_camera", lambda props: cls(props))
        _REGISTERED.add(variant)
    return mi


def _wall_camera_class(mi):
    """A pinhole camera looking through the curved PMMA wall.

    Every camera ray is refracted by Snell's law at the outer and inner
    cylinder surfaces (the same geometry as :meth:`_Cell.rays`) or, with the
    Fresnel probability, reflected by the outer surface (the lamps' glare);
    the inner surface's reflection is an attenuation (1 - R). The wall itself
    is not a shape of the scene, so the lamps outside light the grains
    directly (next-event estimation works; through a smooth dielectric shape
    it would not, and the grains would only be lit by paths that happen to
    hit a lamp). The random number choosing reflection is the ray time
    (shutter open over [0, 1]; nothing in the scene moves); reflection is
    chosen with probability GLARE_SHARE and weighted.
    """
    import drjit as dr

    def fresnel(cos_i, n1, n2):
        sin_t2 = (n1 / n2) ** 2 * dr.maximum(1 - cos_i * cos_i, 0)
        cos_t = dr.safe_sqrt(1 - sin_t2)
        rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
        rp = (n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)
        return 0.5 * (rs * rs + rp * rp), cos_t

    def hit(o, d, radius):
        a = d.x * d.x + d.z * d.z
        b = 2 * (o.x * d.x + o.z * d.z)
        c = o.x * o.x + o.z * o.z - radius * radius
        return (-b - dr.safe_sqrt(b * b - 4 * a * c)) / (2 * a)

    class WallCamera(mi.Sensor):
        def __init__(self, props):
            super().__init__(props)
            self.p = {k: float(props[k]) for k in ("ox", "oy", "f", "cx", "cy", "cam_y", "cam_z",
                                                   "r_out", "r_in", "ior")}

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
            q = self.p
            size = mi.Vector2f(self.film().crop_size())
            pix = position_sample * size
            u, v = q["ox"] + pix.x - 0.5, q["oy"] + pix.y - 0.5
            d = dr.normalize(mi.Vector3f((u - q["cx"]) / q["f"], -(v - q["cy"]) / q["f"], -1.0))
            o = mi.Point3f(0.0, q["cam_y"], q["cam_z"])
            p1 = o + hit(o, d, q["r_out"]) * d
            n1 = dr.normalize(mi.Vector3f(p1.x, 0.0, p1.z))
            cos1 = -dr.dot(n1, d)
            r1, cos1t = fresnel(cos1, 1.0, q["ior"])
            d_ref = d + 2 * cos1 * n1
            eta = 1.0 / q["ior"]
            d1 = eta * d + (eta * cos1 - cos1t) * n1
            p2 = p1 + hit(p1, d1, q["r_in"]) * d1
            n2 = dr.normalize(mi.Vector3f(p2.x, 0.0, p2.z))
            cos2 = -dr.dot(n2, d1)
            r2, cos2t = fresnel(cos2, q["ior"], 1.0)
            d2 = q["ior"] * d1 + (q["ior"] * cos2 - cos2t) * n2
            # reflection chosen more often than its Fresnel share (the glare is then less noisy), reweighted
            reflect = time < GLARE_SHARE
            origin = dr.select(reflect, p1 + 1e-3 * d_ref, p2)
            direction = dr.select(reflect, d_ref, d2)
            weight = dr.select(reflect, r1 / GLARE_SHARE, (1.0 - r1) * (1.0 - r2) / (1.0 - GLARE_SHARE))
            return mi.Ray3f(origin, direction, 0.0, []), mi.Color3f(weight)

        def sample_ray_differential(self, time, wavelength_sample, position_sample, aperture_sample,
                                    active=True):
            ray, w = self.sample_ray(time, wavelength_sample, position_sample, aperture_sample, active)
            return mi.RayDifferential3f(ray), w

        def to_string(self):
            return "WallCamera[]"

    return WallCamera


def _rgb(v) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(x) for x in v]}


def _bsdfs(name: str, colours: dict[str, tuple[float, float, float]] | None, n_shades: int,
           rng: np.random.Generator) -> list[dict[str, Any]]:
    """A few per-sphere shades of a material's BSDF (the spheres of a batch are not identical)."""
    bsdf = json.loads(json.dumps(PBR_MATERIALS[name]["bsdf"]))
    key = "diffuse_reflectance" if "diffuse_reflectance" in bsdf else "reflectance"
    if colours and name in colours and key in bsdf:
        bsdf[key] = _rgb(colours[name])
    if key not in bsdf:
        return [bsdf]
    out = []
    base = np.array(bsdf[key]["value"])
    for s in np.linspace(0.9, 1.1, n_shades):
        b = json.loads(json.dumps(bsdf))
        b[key] = _rgb(np.clip(base * s * rng.normal(1, 0.01, 3), 0, 0.98))
        out.append(b)
    return out


def _transform(mi, origin, target, up=(0, 1, 0), scale=(1.0, 1.0, 1.0)):
    """Local +z towards target (look_at), after scaling the local axes."""
    t = mi.ScalarTransform4f().look_at(origin=[float(v) for v in origin], target=[float(v) for v in target],
                                       up=[float(v) for v in up])
    return t.scale([float(v) for v in scale])


def _film(canvas, box_filter: bool = False) -> dict[str, Any]:
    rfilter = {"type": "box"} if box_filter else {"type": "gaussian", "stddev": 0.45}
    return {"type": "hdrfilm", "width": int(canvas[2]), "height": int(canvas[3]), "pixel_format": "rgb",
            "rfilter": rfilter}


def _wall_camera(cell: _Cell, canvas) -> dict[str, Any]:
    return {"type": "granseg_wall_camera", "ox": canvas[0], "oy": canvas[1], "f": cell.fx, "cx": cell.cx,
            "cy": cell.cy, "cam_y": cell.y_cam, "cam_z": cell.z_cam, "r_out": R_WALL + WALL_MM,
            "r_in": R_WALL, "ior": PMMA_IOR, "shutter_open": 0.0, "shutter_close": 1.0,
            "film": _film(canvas)}


def _static_scene(mi, cell: _Cell, canvas, lighting: str, lamp_power: float) -> dict[str, Any]:
    """Everything but the grains and the bumps: camera, lid, plate, lamps, room."""
    top = cell.height
    sc: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 12, "rr_depth": 8},
        "sensor": _wall_camera(cell, canvas),
        "pla": PLA,
        "dark": {"type": "diffuse", "reflectance": _rgb([0.02, 0.02, 0.022])},
        "base": {"type": "roughconductor", "material": "Al", "alpha": 0.3},
        # the interior behind the two modelled layers: more grains in shadow
        "inside": {"type": "cylinder", "p0": [0, -1, 0], "p1": [0, top + 1, 0],
                   "radius": cell.rho2 - D_MM, "bsdf": {"type": "ref", "id": "dark"}},
        # plate (rotating, bumps on top) and lid (still, bumps below), 3-D printed PLA
        "plate_rim": {"type": "cylinder", "p0": [0, -14, 0], "p1": [0, 0, 0],
                      "radius": R_WALL - PLATE_GAP, "bsdf": {"type": "ref", "id": "pla"}},
        "plate_top": {"type": "disk", "to_world": _transform(mi, [0, 0, 0], [0, 1, 0], up=[0, 0, 1],
                                                              scale=[R_WALL - PLATE_GAP] * 3),
                      "bsdf": {"type": "ref", "id": "pla"}},
        "table": {"type": "cylinder", "p0": [0, -60, 0], "p1": [0, -14, 0],
                  "radius": R_WALL - 8, "bsdf": {"type": "ref", "id": "base"}},
        "lid_rim": {"type": "cylinder", "p0": [0, top, 0], "p1": [0, top + 14, 0],
                    "radius": R_WALL - PLATE_GAP, "bsdf": {"type": "ref", "id": "pla"}},
        "lid_bottom": {"type": "disk", "to_world": _transform(mi, [0, top, 0], [0, top - 1, 0], up=[0, 0, 1],
                                                               scale=[R_WALL - PLATE_GAP] * 3),
                       "bsdf": {"type": "ref", "id": "pla"}},
        "masses": {"type": "cylinder", "p0": [0, top + 14, 0], "p1": [0, top + 60, 0],
                   "radius": R_WALL - 12, "bsdf": {"type": "ref", "id": "base"}},
        "room": {"type": "constant", "radiance": _rgb([0.02, 0.02, 0.021])},
    }
    if lighting not in LAMPS:
        raise ValueError(f"lighting must be one of {sorted(LAMPS)}, got {lighting!r}")
    target = np.array([0.0, cell.y_cam, R_WALL])
    for k, (azimuth, dist) in enumerate(LAMPS[lighting]):
        a = np.radians(azimuth)
        pos = np.array([dist * np.sin(a), cell.y_cam, dist * np.cos(a)])
        sc[f"lamp{k}"] = {
            "type": "rectangle",
            "to_world": _transform(mi, pos, target, scale=[LAMP_SIZE[0] / 2, LAMP_SIZE[1] / 2, 1]),
            "emitter": {"type": "area", "radiance": _rgb(np.array([1.0, 0.98, 0.95]) * lamp_power)},
        }
    return sc


def _glass_wall_scene(mi, cell: _Cell, canvas) -> dict[str, Any]:
    """A Mitsuba pinhole camera and the wall as a dielectric shell (for checking the wall camera)."""
    fov = np.degrees(2 * np.arctan(canvas[2] / 2 / cell.fx))
    cam = np.array([0.0, cell.y_cam, cell.z_cam])
    top = cell.height
    film = _film(canvas, box_filter=True)
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},  # through both surfaces to a light, no ghosts
        "sensor": {"type": "perspective", "fov": float(fov), "fov_axis": "x", "near_clip": 1.0,
                   "far_clip": 2000.0, "to_world": _transform(mi, cam, cam - [0, 0, 1]), "film": film},
        "pmma": {"type": "dielectric", "int_ior": PMMA_IOR, "ext_ior": 1.0},
        "wall_out": {"type": "cylinder", "p0": [0, -80, 0], "p1": [0, top + 80, 0],
                     "radius": R_WALL + WALL_MM, "bsdf": {"type": "ref", "id": "pmma"}},
        # normals towards the axis: the PMMA is on the outer side
        "wall_in": {"type": "cylinder", "p0": [0, -80, 0], "p1": [0, top + 80, 0],
                    "radius": R_WALL, "flip_normals": True, "bsdf": {"type": "ref", "id": "pmma"}},
    }


class _Bumps:
    """Hemispheres one diameter across on the plate (they turn with it) and under the lid."""

    def __init__(self, cell: _Cell, half_arc_px: float, rng: np.random.Generator):
        self.cell = cell
        theta_max = half_arc_px / cell.d_px * D_MM / cell.rho1 + 0.1
        self.sets = []
        for _lid in (0, 1):
            pts: list[tuple[float, float]] = []
            area = 2 * theta_max * R_WALL * 4 * D_MM
            for _ in range(int(40 * area / BUMP_SPACING**2)):  # dart throwing
                th = rng.uniform(-theta_max, theta_max)
                rho = rng.uniform(R_WALL - 4.5 * D_MM, R_WALL - PLATE_GAP - BUMP_SETBACK - D_MM / 2)
                p = np.array([rho * np.sin(th), rho * np.cos(th)])
                if all(np.hypot(*(p - q)) > 0.85 * BUMP_SPACING for q in pts):
                    pts.append(tuple(p))
            self.sets.append(np.array(pts))

    def centres(self, plate_turn: float) -> list[np.ndarray]:
        """(k, 3) base centres of the plate's bumps (turned by plate_turn rad) and the lid's."""
        out = []
        for lid, pts in enumerate(self.sets):
            rho, th = np.hypot(pts[:, 0], pts[:, 1]), np.arctan2(pts[:, 0], pts[:, 1])
            th = th + (0.0 if lid else plate_turn)
            y = np.full(len(pts), self.cell.height if lid else 0.0)
            out.append(np.stack([rho * np.sin(th), y, rho * np.cos(th)], axis=1))
        return out


def _grains(mi, centres: np.ndarray, radii: np.ndarray, kinds: list[str]) -> dict[str, Any]:
    return {f"g{i:05d}": {"type": "sphere", "center": [float(v) for v in c], "radius": float(r),
                          "bsdf": {"type": "ref", "id": k}}
            for i, (c, r, k) in enumerate(zip(centres, radii, kinds, strict=True))}


def _hemispheres(mi, bumps: list[np.ndarray]) -> dict[str, Any]:
    """Bumps as spheres centred on the plate / lid surface (the hidden half is inside the PLA)."""
    out = {}
    for lid, pts in enumerate(bumps):
        for i, p in enumerate(pts):
            out[f"b{lid}_{i:04d}"] = {"type": "sphere", "center": [float(v) for v in p],
                                      "radius": D_MM / 2, "bsdf": {"type": "ref", "id": "pla"}}
    return out


# --------------------------------------------------------------------------- rendering


def render_pbr_frames(
    c: Any,
    *,
    heavy: str = "steel",
    light: str = "pp",
    particle_diameter_px: float = 34.0,
    image_size: tuple[int, int] = (640, 720),
    camera_matrix: Any = None,
    dist_coeffs: Any = None,
    bottom_shift_px: float | None = None,
    delta_over_H: float = 0.18,
    lighting: str = "two-sided",
    exposure: float = 1.0,
    vignetting: float = 0.2,
    noise: float = 1.0,
    jpeg_quality: int | None = 90,
    colours: dict[str, tuple[float, float, float]] | None = None,
    fps: float = 0.5,
    seed: int = 0,
    spp: int = 64,
    second_layer: bool = True,
    variant: str | None = None,
    out_dir: str | os.PathLike | None = None,
    experiment: dict[str, Any] | None = None,
    force: bool = False,
) -> PbrFrames:
    """Path-trace frames whose per-layer heavy share follows the map ``c``.

    Parameters as :func:`granseg.synth.render_frames`, except:

    heavy, light : steel, ceramic, glass, pom, pp, grey-matte, grey-glossy.
    particle_diameter_px : apparent sphere diameter [undistorted px] at the
        window centre; the camera distance is chosen to give it.
    camera_matrix, dist_coeffs : OpenCV model; fx must equal fy. Default: a
        normal lens, f = 1.5 x width, barrel k1 = -0.25.
    The window is not a parameter: it follows from the geometry (module
    docstring) and is written to the experiment.
    lighting : "two-sided" (an LED panel on each side of the camera), "left" or "front" (one
        panel behind the camera).
    exposure : gain on the automatic exposure of frame 0 (1 = nominal).
    noise : scale of the sensor noise (shot noise of a 1500 e- well, read
        noise 1.5 grey levels); 0 for none.
    jpeg_quality : JPEG quality 1-100, None for PNG.
    colours : {material: (r, g, b)} linear diffuse albedo overrides.
    spp : samples per pixel of the path tracer. The sensor noise draws from the
        generator that also gives each later frame its materials, and its
        Poisson draws use as many numbers as the image asks for: rendered at
        another ``spp``, ``noise``, ``lighting`` or exposure, frame 0 is the
        same scene and the later frames keep their positions but not their
        materials (kept so that the fixtures render as committed).
    second_layer : model the partly hidden second layer of grains.
    variant : mitsuba variant (default llvm_ad_rgb if a libLLVM >= 17 is
        found, else scalar_rgb; or $GRANSEG_MITSUBA_VARIANT).

    Returns
    -------
    PbrFrames (a RenderedFrames) with the frames, the apparent centres and the counts.
    """

    cmap = _check_map(c)
    heavy_key, light_key = _material(heavy), _material(light)
    d = float(particle_diameter_px)
    if not np.isfinite(d) or d < 8:
        raise ValueError(f"particle_diameter_px must be >= 8 px, got {particle_diameter_px!r}")
    w, h = (int(v) for v in image_size)
    k_def, dist_def = _default_camera((w, h))
    k_mat = k_def if camera_matrix is None else np.asarray(camera_matrix, float).reshape(3, 3)
    dist = dist_def if dist_coeffs is None else np.asarray(dist_coeffs, float).ravel()
    n_t, n_layers = cmap.shape
    mi = _mitsuba(variant)
    rng = np.random.default_rng(seed)

    cell = _Cell(k_mat, d, n_layers)
    win = cell.window()
    sensor_map, canvas = _canvas(k_mat, dist, (w, h))
    packing = _Packing(cell, canvas, heavy_key, light_key, second_layer, rng)
    shift = 0.6 * d if bottom_shift_px is None else float(bottom_shift_px)

    shades = 3
    bsdf_ids: dict[str, list[str]] = {}
    base_scene = None
    lamp_power = 80.0
    gain = None
    images, encoded, truth, heights, centres, bump_rows = [], [], [], [], [], []
    n = np.zeros(cmap.shape, dtype=np.int64)
    n_heavy = np.zeros_like(n)
    n_phys, n_heavy_phys = np.zeros_like(n), np.zeros_like(n)
    for i in range(n_t):
        if base_scene is None:
            base_scene = _static_scene(mi, cell, canvas, lighting, lamp_power)
            for key in (heavy_key, light_key):
                if key in bsdf_ids:
                    continue
                bsdf_ids[key] = []
                for s, b in enumerate(_bsdfs(key, colours, shades, rng)):
                    base_scene[f"m_{key}_{s}"] = b
                    bsdf_ids[key].append(f"m_{key}_{s}")
        grains, wall, bump_pts = packing.frame(i, cmap[i], shift, delta_over_H, rng)
        kinds = []
        for hv, s in zip(*grains[2:], strict=True):
            ids = bsdf_ids[heavy_key if hv else light_key]
            kinds.append(ids[s % len(ids)])
        scene = dict(base_scene)
        scene.update(_grains(mi, grains[0], grains[1], kinds))
        scene.update(_hemispheres(mi, bump_pts))
        linear = np.array(mi.render(mi.load_dict(scene), spp=int(spp), seed=int(seed) * 1000 + i))
        # truth of the wall layer
        rows, height, xyzr, counts = _truth(cell, win, *wall, d, n_layers)
        truth.append(rows), heights.append(height), centres.append(xyzr)
        n[i], n_heavy[i], n_phys[i], n_heavy_phys[i] = counts
        bump_rows.append(_bump_rows(cell, win, bump_pts, i, d))
        # the camera
        img = cv2.remap(linear[..., ::-1].astype(np.float32), sensor_map[..., 0], sensor_map[..., 1],
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        if gain is None:
            gain = exposure * _auto_exposure(img)
        image, data = _sensor(img * gain, vignetting, noise, jpeg_quality, rng)
        images.append(image), encoded.append(data)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_raw = np.where(n > 0, n_heavy / np.maximum(n, 1), np.nan)
    meta = _experiment(heavy_key, light_key, cmap, k_mat, dist, win, d, fps, experiment)
    meta["renderer"] = {"name": "granseg.synth.pbr (Mitsuba 3)", "mitsuba": mi.__version__,
                        "variant": mi.variant(), "spp": int(spp), "seed": int(seed), "lighting": lighting,
                        "camera_distance_mm": float(cell.z_cam - cell.rho1)}
    result = PbrFrames(images, truth, n, n_heavy, c_raw, meta, height=heights, n_phys=n_phys,
                       n_heavy_phys=n_heavy_phys, bumps=np.concatenate(bump_rows), c=cmap,
                       centres=centres, encoded=encoded)
    if out_dir is not None:
        result.paths = _write(result, Path(out_dir), jpeg_quality, force)
    return result


class _Packing:
    """The grains in 3-D: the wall layer (each sphere touching the wall, centres from a
    ``frames._Bed`` packing of arc length and height), a second layer further in (its own
    packing) and the bumps of the plate (turning with it) and of the lid."""

    def __init__(self, cell: _Cell, canvas, heavy: str, light: str, second_layer: bool,
                 rng: np.random.Generator):

        self.cell = cell
        d, n_layers = cell.d_px, cell.n_layers
        looks = [dict(MATERIAL_LOOKS.get(k, {}), size_spread=PBR_MATERIALS[k]["size_spread"], name=k)
                 for k in (heavy, light)]
        self.beds = []
        for rho in (cell.rho1, cell.rho2)[: 1 + bool(second_layer)]:
            half = cell.visible_arc(canvas, rho)
            bed_win = np.array([-4.5 * d, 0.0, 4.5 * d, n_layers * d])
            box = (-half + d, 0.0, int(np.ceil(2 * half - 2 * d)), int(n_layers * d))
            self.beds.append((_Bed(bed_win, d, n_layers, box, looks[0], looks[1], rng), rho))
        self.bumps = _Bumps(cell, cell.visible_arc(canvas, cell.rho1), rng)

    def frame(self, i: int, c_row: np.ndarray, shift: float, delta_over_H: float, rng: np.random.Generator):
        """Frame i (frames in order): grains (centres (n, 3), radii, heavy, shade index), the
        wall layer (arc [px], heavy, centres, radii) and the bumps' base centres [mm]."""
        cell, d = self.cell, self.cell.d_px
        # the plate turns with the bottom of the bed; its bumps take the place of grains
        bump_pts = self.bumps.centres(shift * i / d * D_MM / cell.rho1)
        all_bumps = np.concatenate(bump_pts)
        bump_r = np.full(len(all_bumps), D_MM / 2)
        parts = []
        for b, (bed, rho_arc) in enumerate(self.beds):
            x = bed.positions(i, shift, delta_over_H)
            bed.assign_types(x, c_row, rng)
            radii = bed.diam / d * D_MM / 2
            pts = cell.point(x, bed.y, rho_arc, R_WALL - TOUCH_GAP - radii if b == 0 else rho_arc)
            keep = _clear_of(pts, radii, all_bumps, bump_r, BUMP_OVERLAP)
            if b == 0:
                wall = (x[keep], bed.heavy[keep], pts[keep], radii[keep])
            else:
                keep &= _clear_of(pts, radii, parts[0][0], parts[0][1], 0.01 * D_MM)
            parts.append((pts[keep], radii[keep], bed.heavy[keep], np.flatnonzero(keep)))
        grains = tuple(np.concatenate(col) for col in zip(*parts, strict=True))
        return grains, wall, bump_pts


def _material(name: str) -> str:
    key = str(name).strip().lower()
    if key not in PBR_MATERIALS:
        raise ValueError(f"unknown material {name!r}; choose from {sorted(PBR_MATERIALS)}")
    return key


def _clear_of(pts: np.ndarray, radii: np.ndarray, other: np.ndarray, other_r: np.ndarray,
              tolerance: float) -> np.ndarray:
    """Which spheres (pts, radii) overlap none of the others by more than ``tolerance`` [mm]."""
    from scipy.spatial import cKDTree

    if len(other) == 0:
        return np.ones(len(pts), bool)
    dist, j = cKDTree(other).query(pts, k=min(8, len(other)))
    dist, j = dist.reshape(len(pts), -1), j.reshape(len(pts), -1)
    return np.all(dist > radii[:, None] + other_r[j] - tolerance, axis=1)


def _truth(cell: _Cell, win: np.ndarray, x: np.ndarray, is_heavy: np.ndarray, pts: np.ndarray,
           radii: np.ndarray, d: float, n_layers: int):
    """Rows x, y, diameter, heavy, in_window (apparent, undistorted px) of the wall spheres near the window."""
    near = np.abs(x) < 8 * d  # cheap pre-selection on the arc, refined on the image below
    centre, diam, _ = cell.outline(pts[near], radii[near])
    heavy = is_heavy[near]
    height = pts[near, 1] / D_MM
    arc = x[near] / d
    x0, y0, x1, y1 = win
    u, v = centre[:, 0], centre[:, 1]
    close = (u >= x0 - d) & (u < x1 + d) & (v >= y0 - d) & (v < y1 + d)
    inside = (u >= x0) & (u < x1) & (v >= y0) & (v < y1)
    layer = np.clip(np.floor((y1 - v) / (y1 - y0) * n_layers).astype(int), 0, n_layers - 1)
    n = np.bincount(layer[inside], minlength=n_layers)
    nh = np.bincount(layer[inside & heavy], minlength=n_layers)
    inside_p = (np.abs(arc) < 4.5) & (height >= 0) & (height < n_layers)
    layer_p = np.clip(np.floor(height).astype(int), 0, n_layers - 1)
    n_p = np.bincount(layer_p[inside_p], minlength=n_layers)
    nh_p = np.bincount(layer_p[inside_p & heavy], minlength=n_layers)
    rows = np.stack([u, v, diam, heavy.astype(float), inside.astype(float)], axis=1)[close]
    xyzr = np.column_stack([pts[near], radii[near]])[close]
    return rows, height[close], xyzr, (n, nh, n_p, nh_p)


def _bump_rows(cell: _Cell, win: np.ndarray, bump_pts: list[np.ndarray], frame: int, d: float) -> np.ndarray:
    rows = []
    for lid, pts in enumerate(bump_pts):
        near = pts[np.abs(np.arctan2(pts[:, 0], pts[:, 2])) < 9 * D_MM / cell.rho1]
        near = near[np.hypot(near[:, 0], near[:, 2]) > R_WALL - 2 * D_MM]
        if len(near):
            uv = cell.project(near)
            rows.append(np.column_stack([np.full(len(uv), frame), uv, np.full(len(uv), lid)]))
    return np.concatenate(rows) if rows else np.zeros((0, 4))


def _auto_exposure(img: np.ndarray) -> float:
    """Gain putting the 99th percentile of the image centre's brightness at 0.9 of full scale
    (linear), but saturating no more than the brightest 10 % of the whole frame (the lamps'
    glare on the wall, the lid and the plate)."""
    h, w = img.shape[:2]
    lum = img @ np.array([0.0722, 0.7152, 0.2126], np.float32)
    centre = lum[int(0.25 * h):int(0.75 * h), int(0.25 * w):int(0.75 * w)]
    return min(0.9 / max(float(np.percentile(centre, 99)), 1e-6), 1.0 / max(float(np.percentile(lum, 90)), 1e-6))


def _sensor(img: np.ndarray, vignetting: float, noise: float, jpeg_quality: int | None,
            rng: np.random.Generator) -> tuple[np.ndarray, bytes]:
    """Vignetting, shot and read noise (linear), the sRGB curve, 8 bits, JPEG: (image, file bytes)."""
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    img = img * (1 - vignetting * r2)[..., None]
    img = np.clip(img, 0, None)
    if noise > 0:
        well = 1500.0 / noise**2
        img = rng.poisson(img * well).astype(np.float32) / well
        img = img + rng.normal(0, noise * 1.5 / 255, img.shape).astype(np.float32)
    img = np.clip(img, 0, 1)
    srgb = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(img, 1 / 2.4) - 0.055)
    out = np.clip(np.rint(srgb * 255), 0, 255).astype(np.uint8)
    if jpeg_quality is None:
        ok, buf = cv2.imencode(".png", out)
        return out, buf.tobytes()
    ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), buf.tobytes()


def _experiment(heavy, light, cmap, k_mat, dist, win, d, fps, extra) -> dict[str, Any]:
    """The 2-D renderer's experiment.json, named as a PBR look and with docs/formats.md's material spellings."""
    names = {"pom": "POM", "pp": "PP"}  # as docs/formats.md spells them
    base = {"name": f"pbr-{heavy}-{light}", "heavy": names.get(heavy, heavy), "light": names.get(light, light)}
    return frame_experiment(heavy, light, cmap, k_mat, dist, win, d, fps, {**base, **(extra or {})})


# --------------------------------------------------------------------------- files


def _write(result: PbrFrames, out: Path, jpeg_quality: int | None, force: bool) -> list[Path]:
    """Frames (JPEG written once, at the quality asked), experiment.json and truth.npz."""

    out.mkdir(parents=True, exist_ok=True)
    ext = ".png" if jpeg_quality is None else ".jpg"
    paths = []
    for i, data in enumerate(result.encoded):
        p = out / f"frame_{i:04d}{ext}"
        with atomic_path(p, force=force) as tmp:
            tmp.write_bytes(data)
        paths.append(p)
    paths.append(save_json(out / "experiment.json", result.experiment, force=force))
    arrays = _truth_arrays(result)

    def write_npz(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    paths.append(atomic_write(out / "truth.npz", write_npz, force=force))
    return paths


def _truth_arrays(r: PbrFrames) -> dict[str, np.ndarray]:
    """truth.npz: per-sphere rows of all frames stacked (``frame`` says which), float32 (ample: 1e-4 px)."""
    frame = np.concatenate([np.full(len(p), i) for i, p in enumerate(r.particles)])
    f32 = np.float32
    return dict(particles=np.concatenate(r.particles).astype(f32), frame=frame.astype(np.int32),
                height=np.concatenate(r.height).astype(f32), n=r.n, n_heavy=r.n_heavy, c_raw=r.c_raw,
                n_phys=r.n_phys, n_heavy_phys=r.n_heavy_phys, bumps=np.asarray(r.bumps, f32), c=r.c,
                centres=np.concatenate(r.centres).astype(f32))


def load_fixture(path: str | os.PathLike) -> PbrFrames:
    """Read a rendered look (frames, experiment.json, truth.npz) back; does not need mitsuba."""
    p = Path(path)
    frames = sorted(p.glob("frame_*.jpg")) + sorted(p.glob("frame_*.png"))
    if not frames:
        raise FileNotFoundError(f"{p}: no frame_*.jpg / frame_*.png")
    exp_path, truth_path = p / "experiment.json", p / "truth.npz"
    for q in (exp_path, truth_path):
        if not q.is_file():
            raise FileNotFoundError(f"{q}: missing")
    meta = json.loads(exp_path.read_text(encoding="utf-8"))
    with np.load(truth_path) as z:
        t = {k: z[k] for k in z.files}
    n_t = t["n"].shape[0]
    if len(frames) != n_t:
        raise ValueError(f"{p}: {len(frames)} frames but truth.npz has {n_t}")
    images = []
    for f in frames:
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            raise OSError(f"{f}: could not read image")
        images.append(img)
    particles = [t["particles"][t["frame"] == i].astype(float) for i in range(n_t)]
    height = [t["height"][t["frame"] == i].astype(float) for i in range(n_t)]
    centres = [t["centres"][t["frame"] == i].astype(float) for i in range(n_t)]
    return PbrFrames(images, particles, t["n"], t["n_heavy"], t["c_raw"], meta, paths=[*frames, exp_path],
                     height=height, n_phys=t["n_phys"], n_heavy_phys=t["n_heavy_phys"],
                     bumps=t["bumps"].astype(float), c=t["c"], centres=centres)


# --------------------------------------------------------------------------- fixtures


def fixture_map(n_t: int, c0: float, n_layers: int = 15) -> np.ndarray:
    """Heavy share per layer: stratified at t = 0 (heavy above (1 - c0) H), mixing towards a gradient."""
    z = (np.arange(n_layers) + 0.5) / n_layers
    t = np.linspace(0, 1, n_t)[:, None]
    start = (z > 1 - c0).astype(float)
    end = np.clip(c0 + 0.8 * min(c0, 1 - c0) * (0.5 - z), 0, 1)
    return np.clip(start * (1 - t) + end * t, 0, 1)


def _verify(mi, result: PbrFrames, spp: int = 128) -> dict[str, Any]:
    """Check the truth of the first frame against masks that Mitsuba renders.

    Every sphere in the window is rendered as a light, the other grains
    removed, in batches of spheres far apart, (a) with Mitsuba's own pinhole
    camera behind the wall modelled as a dielectric shell (``dielectric``
    cylinders, IOR 1.49: independent of the analytic trace) and (b) with the
    wall camera that renders the footage. Each mask's weighted centroid and
    area give an apparent centre and diameter [undistorted px].
    """
    meta = result.experiment
    k_mat = np.asarray(meta["camera_matrix"], float)
    d = float(meta["particle_diameter_px"])
    cell = _Cell(k_mat, d, result.n.shape[1])
    _, canvas = _canvas(k_mat, np.asarray(meta["dist_coeffs"], float), result.images[0].shape[1::-1])
    rows = result.particles[0]
    sel = rows[:, 4] > 0
    uv, diam = rows[sel, :2], rows[sel, 2]
    pts, radii = result.centres[0][sel, :3], result.centres[0][sel, 3]
    proj = cell.project(pts)
    shell = _glass_wall_scene(mi, cell, canvas)
    camera = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
              "sensor": dict(_wall_camera(cell, canvas), film=_film(canvas, box_filter=True))}
    masks = {name: _mask_centres(mi, base, pts, radii, uv, d, canvas, spp)
             for name, base in (("shell", shell), ("camera", camera))}

    def stats(a, b):
        e = np.hypot(*(a - b).T)
        return {"mean": round(float(e.mean()), 4), "p95": round(float(np.percentile(e, 95)), 4),
                "max": round(float(e.max()), 4)}

    (c_shell, d_shell), (c_cam, _) = masks["shell"], masks["camera"]
    return {"spheres": int(len(uv)), "mask_spp": int(spp),
            "truth_vs_shell_mask_px": stats(uv, c_shell),
            "projected_centre_vs_shell_mask_px": stats(proj, c_shell),
            "truth_vs_projected_centre_px": stats(uv, proj),
            "wall_camera_mask_vs_shell_mask_px": stats(c_cam, c_shell),
            "diameter_minus_shell_mask_px": {"mean": round(float(np.mean(diam - d_shell)), 4),
                                             "max_abs": round(float(np.max(np.abs(diam - d_shell))), 4)}}


def _mask_centres(mi, base: dict[str, Any], pts, radii, uv, d, canvas, spp) -> tuple[np.ndarray, np.ndarray]:
    ox, oy = canvas[0], canvas[1]
    todo = list(range(len(pts)))
    centres, sizes = np.zeros((len(pts), 2)), np.zeros(len(pts))
    while todo:
        batch: list[int] = []
        for i in list(todo):
            # spheres sharing a colour channel stay apart; no two touch (they would hide each other's rim)
            chan = len(batch) % 3
            gaps = [np.hypot(*(uv[i] - uv[j])) / d - (2.6 if p % 3 == chan else 1.6) for p, j in enumerate(batch)]
            if all(g > 0 for g in gaps):
                batch.append(i)
                todo.remove(i)
        scene = dict(base)
        for b, i in enumerate(batch):
            rgb = np.zeros(3)
            rgb[b % 3] = 1.0
            scene[f"s{b}"] = {"type": "sphere", "center": [float(v) for v in pts[i]], "radius": float(radii[i]),
                              "emitter": {"type": "area", "radiance": _rgb(rgb)}}
        img = np.array(mi.render(mi.load_dict(scene), spp=spp, seed=len(todo)))
        r = int(np.ceil(0.9 * d))
        for b, i in enumerate(batch):
            cu, cv = int(round(uv[i, 0] - ox)), int(round(uv[i, 1] - oy))
            x_a, y_a = max(cu - r, 0), max(cv - r, 0)
            patch = img[y_a:cv + r + 1, x_a:cu + r + 1, b % 3]
            full = np.median(patch[patch > 0.5 * patch.max()])
            wgt = patch / full  # not clipped at 1: the Fresnel noise inside averages out
            yy, xx = np.mgrid[0:patch.shape[0], 0:patch.shape[1]]
            centres[i] = ((wgt * xx).sum() / wgt.sum() + x_a + ox, (wgt * yy).sum() / wgt.sum() + y_a + oy)
            sizes[i] = np.sqrt(4 * wgt.sum() / np.pi)
    return centres, sizes


def render_fixtures(out: Path, looks: list[str] | None = None, spp: int = FIXTURE_SPP, force: bool = False,
                    frames: int = FIXTURE_FRAMES, verify: bool = True, seed_offset: int = 0,
                    lens: bool = True) -> None:
    """Render the looks of FIXTURE_LOOKS into out/<look>/ and write out/verification.json.

    ``seed_offset`` renders other packings of the same looks: the tuning
    family (TUNING_SEED_OFFSET) that the detector may be developed on, kept
    apart from the committed fixtures it is judged on. ``lens=False``
    renders them through a camera without distortion (a control: what the
    lens and its taking off do to the detector).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = looks or list(FIXTURE_LOOKS)
    report_path = out / "verification.json"
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    for name in names:
        args = dict(FIXTURE_LOOKS[name])
        args["seed"] += seed_offset
        c0 = args.pop("c0")
        args["experiment"] = {"name": f"pbr-{name}", "c0": c0, **args.get("experiment", {})}
        if not lens:
            args["dist_coeffs"] = np.zeros(5)
        t0 = time.perf_counter()
        r = render_pbr_frames(fixture_map(frames, c0), particle_diameter_px=FIXTURE_D_PX,
                              image_size=FIXTURE_SIZE, jpeg_quality=FIXTURE_JPEG, noise=FIXTURE_NOISE,
                              spp=spp, out_dir=out / name, force=force, **args)
        seconds = time.perf_counter() - t0
        entry: dict[str, Any] = {"render_seconds": round(seconds, 1), "frames": frames, "spp": spp}
        if verify:
            entry.update(_verify(_mitsuba(None), r))
        entry["apparent_vs_true_layer_differ"] = _layer_mismatch(r)
        report[name] = entry
        print(f"{name}: {seconds:.0f} s, {json.dumps(entry)}", flush=True)

        save_json(report_path, report, force=True)


def _layer_mismatch(r: PbrFrames) -> float:
    """Share of spheres in the window whose apparent layer differs from their true one."""
    y0, y1 = r.experiment["window"][1], r.experiment["window"][3]
    n_layers = r.n.shape[1]
    bad = tot = 0
    for p, h in zip(r.particles, r.height, strict=True):
        inside = p[:, 4] > 0
        app = np.clip(np.floor((y1 - p[inside, 1]) / (y1 - y0) * n_layers), 0, n_layers - 1)
        bad += int(np.sum(app != np.clip(np.floor(h[inside]), 0, n_layers - 1)))
        tot += int(inside.sum())
    return round(bad / max(tot, 1), 4)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m granseg.synth.pbr",
                                 description="Render the physically based test fixtures.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    fx = sub.add_parser("fixtures", help="render FIXTURE_LOOKS into OUT_DIR/<look>/")
    fx.add_argument("out_dir", type=Path)
    fx.add_argument("--looks", default=None, help="comma-separated subset of: " + ", ".join(FIXTURE_LOOKS))
    fx.add_argument("--spp", type=int, default=FIXTURE_SPP)
    fx.add_argument("--frames", type=int, default=FIXTURE_FRAMES)
    fx.add_argument("--no-verify", action="store_true")
    fx.add_argument("--force", action="store_true", help="overwrite existing files")
    fx.add_argument("--seed-offset", type=int, default=0,
                    help=f"render other packings of the looks ({TUNING_SEED_OFFSET}: the tuning family)")
    fx.add_argument("--no-lens", action="store_true", help="a camera without distortion (a control)")
    a = ap.parse_args(argv)
    looks = a.looks.split(",") if a.looks else None
    for name in looks or []:
        if name not in FIXTURE_LOOKS:
            ap.error(f"unknown look {name!r}; choose from {', '.join(FIXTURE_LOOKS)}")
    render_fixtures(a.out_dir, looks, a.spp, a.force, a.frames, not a.no_verify, a.seed_offset, not a.no_lens)
    return 0


if __name__ == "__main__":
    sys.exit(main())
