"""Synthetic side-wall frames of the shear cell, with exact ground truth.

:func:`render_frames` draws what the camera sees through the transparent
outer wall: spheres in a random dense (jammed) packing against the wall,
sheared sideways with the wall-adjacent velocity profile (fast at the bottom
plate, still under the lid), shaded by material (metallic steel, white ceramic,
transparent glass, dark POM, coloured polypropylene), seen through a
barrel-distorting lens given as an OpenCV camera model, with blur, sensor
noise and JPEG artefacts. Optional apparatus features: the bumpy lid and
plate (hemispheres on the horizontal walls, which are not grains), motion
blur of the fast lower layers, reflections of the lamps on the curved PMMA
wall, dust and scratches on the wall, and lossy video (MPEG-4 Part 2 or
H.264) instead of still frames. Which grains are heavy follows a given
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

from granseg._io import atomic_path, cv2_path, save_json

__all__ = ["MATERIAL_LOOKS", "VIDEO_CODECS", "RenderedFrames", "default_camera", "render_frames",
           "render_checkerboard"]

# How each material looks. colour: B, G, R in [0, 1]; kd/ks: diffuse and
# specular weights; shininess: Blinn-Phong exponent; metal: mirror-like
# reflection of the surroundings; glass: transparent, shows the grains behind;
# size_spread: relative standard deviation of the diameter. Optional keys:
# material: the docs/model.md material whose density the look takes (default: the
# look's own name); mirror: a polished metal that shows a sharp image of its
# surroundings (dark lab and camera, lit ceiling, the lamps' panels) rather
# than the soft sheen of ``metal``.
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
    # Polished (mirror-finish) bearing steel: a mirror of its surroundings,
    # dark where it shows the camera, the lab and the bed, a bright cap where
    # it shows the lit room above, and sharp-edged images of the two lamp
    # panels; on average hardly brighter than dark POM.
    "steel-polished": dict(colour=(0.66, 0.66, 0.68), kd=0.0, ks=0.6, shininess=600, metal=True,
                           glass=False, size_spread=0.004, material="steel", mirror=True),
    # Light-grey filled POM, matte: a mid grey with a faint broad sheen.
    "pom-grey": dict(colour=(0.43, 0.43, 0.44), kd=0.9, ks=0.10, shininess=10, metal=False,
                     glass=False, size_spread=0.01, material="pom"),
    # Glossy grey polypropylene: nearly the mean brightness of pom-grey (a
    # little darker body, a small strong highlight), so the two differ in gloss only.
    "pp-grey": dict(colour=(0.42, 0.42, 0.43), kd=0.9, ks=0.75, shininess=90, metal=False,
                    glass=False, size_spread=0.008, material="pp"),
    # Matte dark-grey polypropylene: pom-grey's finish a shade darker, so the
    # two differ in brightness only, as a lamp's fall-off down the bed does.
    "pp-matte-grey": dict(colour=(0.34, 0.34, 0.35), kd=0.9, ks=0.10, shininess=10, metal=False,
                          glass=False, size_spread=0.01, material="pp"),
}

# Printed PLA of the bumpy lid and plate (the paper's horizontal walls): matte light grey.
WALL_LOOK: dict[str, Any] = dict(colour=(0.52, 0.52, 0.54), kd=0.85, ks=0.25, shininess=15, metal=False,
                                 glass=False, size_spread=0.0, name="pla")

# Video codecs of render_frames(video=...): MPEG-4 Part 2 through OpenCV, H.264 through PyAV (libx264).
VIDEO_CODECS = ("mp4v", "h264")
VIDEO_PLAYBACK_FPS = 30.0  # frame rate stored in the video file (a GoPro time-lapse video plays at 30 fps)
VIDEO_BITS_PER_PIXEL = 0.25  # default bitrate of an encoder that takes one: bits per pixel and frame

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
    paths: files written (frames or the video, then experiment.json), empty if none.
    bumps: per frame, a (k, 4) float array of the bumps of the lid and plate
        (``bumps=True``) within one diameter of the window: x, y [undistorted
        px] of the centre of the hemisphere's sphere (on the wall's surface:
        y = y0 for the lid, y1 for the plate), diameter [px], on_plate (1/0).
        They are not grains: never in ``particles`` nor in the counts. Empty
        (0, 4) arrays without bumps.
    source: what to give :func:`granseg.measure.analyze`: the frames
        directory or the video file (None if nothing was written).
    """

    images: list[np.ndarray]
    particles: list[np.ndarray]
    n: np.ndarray
    n_heavy: np.ndarray
    c_raw: np.ndarray
    experiment: dict[str, Any]
    paths: list[Path] = field(default_factory=list)
    bumps: list[np.ndarray] = field(default_factory=list)
    source: Path | None = None


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
    exposure_drift: float = 0.0,
    vignetting: float = 0.25,
    light_from_above: float = 0.0,
    blur: float = 0.7,
    noise: float = 2.0,
    jpeg_quality: int | None = None,
    colours: dict[str, tuple[float, float, float]] | None = None,
    fps: float = 0.5,
    seed: int = 0,
    out_dir: str | os.PathLike | None = None,
    experiment: dict[str, Any] | None = None,
    force: bool = False,
    bumps: bool = False,
    bump_spacing: float = 3.0,
    smear_diameters: float = 0.0,
    wall_reflections: float = 0.0,
    dust: int = 0,
    video: str | None = None,
    video_bitrate: float | None = None,
    lid_slip: float = 0.0,
    exact_speeds: bool = False,
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
    exposure_drift : a camera's automatic exposure changing over the run:
        the gain grows linearly from ``exposure`` at the first frame to
        ``exposure * (1 + exposure_drift)`` at the last (-0.25: a quarter
        darker by the end). 0: steady.
    vignetting : relative darkening at the image corners.
    light_from_above : relative darkening from the image's top to its bottom, as
        under a lamp above the cell (0.4: the bottom gets 60 % of the top's
        light). A look that changes with height, as the first frame's heavy
        spheres all sit high: 0, none.
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
    bumps : draw the bumpy lid and plate: hemispheres one diameter across,
        their flat side on the wall, along the top (y0) and bottom (y1) of
        the bed, at random centre spacings of 0.7-1.3 x ``bump_spacing``
        diameters (the paper's 2 D between edges: 3 D). The plate's bumps
        move by ``bottom_shift_px`` per frame, the lid's stay; the grains
        pack around them. They are not grains: their positions come back in
        ``RenderedFrames.bumps``, never in the counts.
    smear_diameters : motion blur: the horizontal smear of a grain touching
        the plate during one exposure, in diameters (plate speed x exposure
        / D; the paper's 0.17 m/s at 1/60 s over 6 mm spheres: 0.47);
        higher up the smear decays with the shift's profile, the plate's
        bumps smear by the full length. The true centre is the centre of the
        smear (mid-exposure). 0: sharp.
    wall_reflections : strength of the lamps' reflections on the curved PMMA
        wall (1 = typical, ``True`` = 1): soft-edged bright vertical bands, a
        few px to a diameter wide, static over the frames, over everything behind.
    dust : number of dust specks (small dark or bright dots) on the wall; one
        thin scratch comes with every eight specks (at least one). Static.
    video : None for still frames, else write (and return, decoded) a lossy
        video: "mp4v" (MPEG-4 Part 2 by OpenCV's VideoWriter, which sets the
        bitrate itself) or "h264" (libx264 through PyAV: ``pip install
        av``). The file ``video.mp4`` in ``out_dir`` plays at 30 fps (a
        GoPro time-lapse video); ``fps`` stays the capture rate in
        experiment.json. Without ``out_dir`` the video is encoded in a
        temporary file and only the decoded frames are kept.
    video_bitrate : bits per second at the 30 fps playback rate; default
        (h264) 0.25 bit per pixel and frame, where compression artefacts
        show. With "mp4v" a bitrate needs PyAV (its MPEG-4 Part 2 encoder).

    lid_slip : the lid's speed over the plate's, v1 / v0 (rows move by
        ``bottom_shift_px * (lid_slip + (1 - lid_slip) exp(-z / delta))``).
    exact_speeds : every half-diameter band moves exactly at the profile's
        mean speed (the last relaxation's drift taken off): footage whose
        velocity profile is known (:mod:`granseg.synth.highspeed`).

    Returns
    -------
    RenderedFrames with the images, the exact centres and the per-layer counts.
    """
    cmap = _check_map(c)
    if not (np.isfinite(lid_slip) and 0.0 <= lid_slip < 1.0):
        raise ValueError(f"lid_slip must be in [0, 1) (v1 / v0), got {lid_slip!r}")
    if not (np.isfinite(exposure_drift) and exposure_drift > -1.0):
        raise ValueError(f"exposure_drift must be > -1 (the last frame's gain stays positive), got {exposure_drift!r}")
    if not (np.isfinite(light_from_above) and 0.0 <= light_from_above < 1.0):
        raise ValueError(f"light_from_above must be in [0, 1) (the bottom's light stays positive), got {light_from_above!r}")
    heavy_look, light_look = _look(heavy, colours), _look(light, colours)
    apparatus = _apparatus(bumps, bump_spacing, smear_diameters, wall_reflections, dust, video, video_bitrate)
    d = float(particle_diameter_px)
    if not np.isfinite(d) or d < 8:
        raise ValueError(f"particle_diameter_px must be >= 8 px, got {particle_diameter_px!r}")
    w, h = (int(v) for v in image_size)
    k_mat, dist = _camera(camera_matrix, dist_coeffs, (w, h))
    win = _window(window, d, cmap.shape[1], (w, h))
    rng = np.random.default_rng(seed)
    # apparatus features draw from their own generator, so that the packing,
    # the types and the noise of a scene do not depend on them
    arng = np.random.default_rng([int(seed), 1])
    sensor_map, canvas_box = _distortion_map(k_mat, dist, (w, h), d)
    walls = _Bumps(win, d, canvas_box, apparatus["bump_spacing"], arng) if apparatus["bumps"] else None
    bed = _Bed(win, d, cmap.shape[1], canvas_box, heavy_look, light_look, rng, walls)
    scene = _Scene(canvas_box, win, d, heavy_look, light_look, lighting, rng,
                   apparatus=apparatus, delta_over_H=delta_over_H, arng=arng)
    shift = 0.6 * d if bottom_shift_px is None else float(bottom_shift_px)
    images, truth, bump_truth = [], [], []
    n = np.zeros(cmap.shape, dtype=np.int64)
    n_heavy = np.zeros(cmap.shape, dtype=np.int64)
    for i in range(cmap.shape[0]):
        x = bed.positions(i, shift, delta_over_H, lid_slip, exact_speeds)
        bed.assign_types(x, cmap[i], rng)
        gain = exposure * (1.0 + exposure_drift * i / max(cmap.shape[0] - 1, 1))
        ideal = scene.draw(x, bed, gain, vignetting, light_from_above)
        images.append(_camera_effects(ideal, sensor_map, blur, noise, jpeg_quality, rng))
        truth.append(bed.truth(x))
        bump_truth.append(bed.bump_truth())
        n[i], n_heavy[i] = bed.layer_counts(x)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_raw = np.where(n > 0, n_heavy / np.maximum(n, 1), np.nan)
    meta = _experiment(heavy, light, cmap, k_mat, dist, win, d, fps, experiment)
    result = RenderedFrames(images, truth, n, n_heavy, c_raw, meta, bumps=bump_truth)
    if video is not None:
        result.images, result.paths = _video(result, apparatus, out_dir, force)
        result.source = result.paths[0] if result.paths else None
    elif out_dir is not None:
        result.paths = _write(result, Path(out_dir), jpeg_quality, force)
        result.source = Path(out_dir)
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


def _apparatus(bumps, bump_spacing, smear, reflections, dust, video, bitrate) -> dict[str, Any]:
    """The apparatus options, checked."""
    spacing, smear, refl = float(bump_spacing), float(smear), float(reflections)
    if not (np.isfinite(spacing) and spacing >= 1.5):
        raise ValueError(f"bump_spacing must be >= 1.5 diameters, got {bump_spacing!r}")
    if not (np.isfinite(smear) and 0 <= smear <= 5):
        raise ValueError(f"smear_diameters must be in [0, 5], got {smear!r}")
    if not (np.isfinite(refl) and refl >= 0):
        raise ValueError(f"wall_reflections must be >= 0, got {reflections!r}")
    if isinstance(dust, bool) or int(dust) != dust or dust < 0:
        raise ValueError(f"dust must be a whole number of specks >= 0, got {dust!r}")
    if video is not None and video not in VIDEO_CODECS:
        raise ValueError(f"video must be None or one of {VIDEO_CODECS}, got {video!r}")
    if bitrate is not None and not (np.isfinite(float(bitrate)) and float(bitrate) > 0):
        raise ValueError(f"video_bitrate must be > 0 bits/s, got {bitrate!r}")
    return dict(bumps=bool(bumps), bump_spacing=spacing, smear=smear, reflections=refl, dust=int(dust),
                video=video, bitrate=None if bitrate is None else float(bitrate))


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

    def __init__(self, win, d, n_layers, box, heavy_look, light_look, rng, walls=None):
        self.win, self.d, self.n_layers = win, d, n_layers
        ox, _, cw, _ = box
        self.x_lo, self.length = ox - d, cw + 2 * d
        self.walls = walls  # the bumps of lid and plate: fixed obstacles, or None
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

        n = self.y.size
        # the bumps of the lid and plate are obstacles that never give way (mobility 0)
        bx, by, bd = (np.zeros(0),) * 3 if self.walls is None else self.walls.centres()
        r = np.concatenate([self.diam, bd]) / 2
        y_lo, y_hi = self.win[1] + r[:n], self.win[3] - r[:n]
        box = (self.length, 4 * (self.win[3] - self.win[1]) + 4 * self.d)
        pairs = None
        for sweep in range(sweeps):
            xs, ys = np.concatenate([self.x0, bx]), np.concatenate([self.y, by])
            if sweep % 10 == 0:  # neighbour list with a skin, rebuilt every 10 sweeps
                pts = np.column_stack([xs % self.length, ys - self.win[1] + self.d])
                pairs = cKDTree(pts, boxsize=box).query_pairs(1.3 * max(self.diam.max(), bd.max(initial=0)),
                                                              output_type="ndarray").T
                pairs = pairs[:, pairs[0] < n]  # query_pairs gives i < j: i is always a grain
            i, j = pairs
            dx = xs[j] - xs[i]
            dx -= self.length * np.rint(dx / self.length)
            dy = ys[j] - ys[i]
            dist = np.hypot(dx, dy)
            overlap = r[i] + r[j] - dist
            hit = overlap > 0.002 * self.d
            if not hit.any():
                break
            i, j, dx, dy, dist, overlap = i[hit], j[hit], dx[hit], dy[hit], dist[hit], overlap[hit]
            dist = np.maximum(dist, 1e-6)
            # push each sphere of the pair half the overlap (and a little more, to converge)
            mob = np.ones_like(self.y) if mobility is None else mobility
            mob = np.concatenate([mob, np.zeros(bx.size)])
            share_i = mob[i] / (mob[i] + mob[j])
            ux, uy = dx / dist * 1.1 * overlap, dy / dist * 1.1 * overlap
            mx, my = np.zeros(n + bx.size), np.zeros(n + bx.size)
            np.add.at(mx, i, -ux * share_i), np.add.at(mx, j, ux * (1 - share_i))
            np.add.at(my, i, -uy * share_i), np.add.at(my, j, uy * (1 - share_i))
            mx, my = mx[:n], my[:n]
            if shake and sweep < sweeps // 2:  # shake early on, so the packing does not lock into a crystal
                mx += rng.normal(0, 0.01 * self.d, mx.size)
                my += rng.normal(0, 0.01 * self.d, my.size)
            self.x0 = (self.x0 + mx) % self.length
            self.y = np.clip(self.y + my, y_lo, y_hi)

    def positions(self, frame: int, shift: float, delta_over_H: float, slip: float = 0.0,
                  exact: bool = False) -> np.ndarray:
        """x [undistorted px] of every sphere at ``frame`` (frames come in order; the bed shears).

        Each height moves by shift * (slip + (1 - slip) exp(-z / delta)) on average (``slip``:
        the lid's speed over the plate's). The last relaxation sweeps, which remove the
        overlaps the shear leaves, slow the fastest grains a little; ``exact`` takes their
        drift off too, so every half-diameter band moves exactly at the profile's mean
        speed (high-speed footage with a known profile; overlaps of a fraction of a pixel remain).
        """
        if frame > 0:
            if self.walls is not None:
                self.walls.advance(shift)  # the plate (and its bumps) moves by the full bottom shift
            height = self.win[3] - self.win[1]
            profile = slip + (1.0 - slip) * np.exp(-(self.win[3] - self.y) / (delta_over_H * height))
            before = self.x0 + shift * profile
            self.x0 = before % self.length
            for _ in range(3):
                # grains make room for each other, but each height keeps its mean speed
                self._relax(SHEAR_SWEEPS, self.rng, mobility=profile + 1e-3)
                self._keep_band_means(before)
            self._relax(SHEAR_SWEEPS, self.rng, mobility=profile + 1e-3)
            if exact:
                self._keep_band_means(before)
        return self.x_lo + self.x0

    def _keep_band_means(self, before: np.ndarray) -> None:
        """Take off each half-diameter band's mean drift from ``before`` (the sheared positions)."""
        moved = (self.x0 - before + self.length / 2) % self.length - self.length / 2
        band = np.clip(((self.y - self.win[1]) / (0.5 * self.d)).astype(int), 0, None)
        mean = np.bincount(band, moved) / np.maximum(np.bincount(band), 1)
        self.x0 = (self.x0 - mean[band]) % self.length

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

    def bump_truth(self) -> np.ndarray:
        """(k, 4): x, y, diameter, on_plate of the bumps within one diameter of the window."""
        if self.walls is None:
            return np.zeros((0, 4))
        bx, by, bd = self.walls.centres()
        x = self.x_lo + bx
        x0, _, x1, _ = self.win
        near = (x >= x0 - self.d) & (x < x1 + self.d)
        return np.column_stack([x, by, bd, self.walls.on_plate])[near]


class _Bumps:
    """The hemispheres on the lid and the plate, one diameter across, along the wall.

    In the bed's periodic coordinate (0 .. length, like ``_Bed.x0``): random
    centre spacings of 0.7 to 1.3 x ``spacing`` diameters. The plate's bumps
    advance with the plate; the lid's are fixed.
    """

    def __init__(self, win, d, box, spacing, rng):
        ox, _, cw, _ = box
        self.length = cw + 2 * d
        rows = [self._row(d, spacing, rng) for _ in range(2)]
        self.x_lid, self.x_plate = rows
        self.y = np.concatenate([np.full(rows[0].size, win[1]), np.full(rows[1].size, win[3])])
        self.diam = np.full(self.y.size, float(d))
        self.on_plate = np.concatenate([np.zeros(rows[0].size), np.ones(rows[1].size)])
        self.offset = 0.0

    def _row(self, d, spacing, rng) -> np.ndarray:
        gaps = rng.uniform(0.7, 1.3, int(self.length / (0.7 * spacing * d)) + 2) * spacing * d
        x = np.concatenate([[0.0], np.cumsum(gaps)])
        x = x[x <= self.length - 0.7 * spacing * d]  # the gap across the wrap-around is >= 0.7 x spacing too
        return (x + rng.uniform(0, self.length)) % self.length

    def advance(self, shift: float) -> None:
        self.offset += shift

    def centres(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x (periodic coordinate), y [undistorted px], diameter [px] of every bump."""
        x = np.concatenate([self.x_lid, (self.x_plate + self.offset) % self.length])
        return x, self.y, self.diam


# --------------------------------------------------------------------------- drawing


class _Scene:
    """Draws the ideal (undistorted, noise-free) image of the wall, float BGR in [0, 1]."""

    def __init__(self, box, win, d, heavy_look, light_look, lighting, rng, apparatus=None,
                 delta_over_H=0.18, arng=None):
        if lighting not in LIGHTINGS:
            raise ValueError(f"lighting must be one of {sorted(LIGHTINGS)}, got {lighting!r}")
        self.ox, self.oy, self.cw, self.ch = box
        self.win, self.d = win, d
        self.looks = (light_look, heavy_look)
        self.lights = LIGHTINGS[lighting]
        self.app = apparatus or dict(bumps=False, smear=0.0, reflections=0.0, dust=0)
        self.delta_over_H = float(delta_over_H)
        arng = np.random.default_rng(1) if arng is None else arng
        self.behind = self._behind(heavy_look, light_look, rng)
        self.base = self._bumpy_walls(arng) if self.app["bumps"] else self._walls()
        self.overlay = self._wall_overlay(arng) if self.app["reflections"] > 0 or self.app["dust"] > 0 else None

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

    def _bumpy_walls(self, arng) -> np.ndarray:
        """The bumpy lid and plate seen edge-on: printed PLA (fine horizontal
        layer lines), a bright chamfer along each edge, a shadow under the lid."""
        img = self.behind * 0.3
        yy = np.arange(self.ch) + self.oy
        y0, y1 = self.win[1], self.win[3]
        layers = (1 + 0.05 * cv2.GaussianBlur(arng.normal(0, 1, (self.ch, 1)), (1, 0), 0.6)[:, 0]).astype(np.float32)
        base = np.array(WALL_LOOK["colour"], np.float32)
        lid, plate = yy < y0, yy >= y1
        fade_lid = np.clip(1 - (y0 - yy[lid]) / (6 * self.d), 0.7, 1)  # lit from the side: brightest near the bed
        img[lid] = base * (fade_lid * layers[lid])[:, None, None]
        img[plate] = base * 0.8 * layers[plate][:, None, None]
        for y_edge, value, width in ((y0, 0.55, 1.2), (y1, 0.50, 1.5)):
            line = np.exp(-((yy - y_edge) / width) ** 2).astype(np.float32)
            img += (value - img) * line[:, None, None]
        below_lid = (yy >= y0) & (yy < y0 + 0.4 * self.d)
        img[below_lid] *= (0.6 + 0.4 * (yy[below_lid] - y0) / (0.4 * self.d))[:, None, None].astype(np.float32)
        return img

    def _wall_overlay(self, arng) -> tuple[np.ndarray, np.ndarray]:
        """Static marks on the PMMA wall: (mul (H, W), add (H, W, 3)) over the lit image.

        Lamp reflections: each lamp's mirror image in the curved wall is a
        soft vertical band on the lamp's side (a fainter, narrower one beside
        it from the wall's inner surface). Dust: small dark (blocking) or
        bright (scattering) specks; scratches: thin bright lines.
        """
        mul = np.ones((self.ch, self.cw), np.float32)
        add = np.zeros((self.ch, self.cw), np.float32)
        xx = np.arange(self.cw) + self.ox
        yy = np.arange(self.ch) + self.oy
        x0, y0, x1, y1 = self.win
        mid, half = (x0 + x1) / 2, (x1 - x0) / 2
        strength = self.app["reflections"]
        if strength > 0:
            for lx, _, _, power in self.lights:
                side = np.sign(lx) if abs(lx) > 0.1 else arng.choice([-1.0, 1.0])
                reach = arng.uniform(0.25, 0.9) if abs(lx) > 0.1 else arng.uniform(0.0, 0.3)
                xc = mid + side * reach * half
                for offset, width, peak, edge in ((0.0, arng.uniform(0.35, 1.0) * self.d, 0.30, 3),
                                                  (side * arng.uniform(0.4, 1.2) * self.d,
                                                   max(3.0, arng.uniform(0.1, 0.25) * self.d), 0.07, 2)):
                    u = np.abs(xx - xc - offset) / (width / 2)
                    across = np.exp(-u ** edge)
                    wobble = cv2.GaussianBlur(arng.normal(0, 1, (self.ch, 1)), (1, 0), self.d)[:, 0]
                    along = 1 - 0.25 * ((yy - (y0 + y1) / 2) / (y1 - y0)) ** 2 + 3.0 * wobble
                    add += (strength * peak * power / 0.65 * np.outer(np.clip(along, 0.3, 1.3), across)).astype(np.float32)
        n_dust = self.app["dust"]
        if n_dust > 0:
            scale = max(1.0, self.d / 30)
            for _ in range(n_dust):
                px = arng.uniform(x0 - self.d, x1 + self.d) - self.ox
                py = arng.uniform(y0 - self.d, y1 + self.d) - self.oy
                rad = arng.uniform(0.4, 1.6) * scale
                lo_x, hi_x = max(int(px - 3 * rad), 0), min(int(px + 3 * rad) + 2, self.cw)
                lo_y, hi_y = max(int(py - 3 * rad), 0), min(int(py + 3 * rad) + 2, self.ch)
                gx, gy = np.meshgrid(np.arange(lo_x, hi_x) - px, np.arange(lo_y, hi_y) - py)
                spot = np.exp(-(gx * gx + gy * gy) / (rad * rad)).astype(np.float32)
                if arng.uniform() < 0.7:
                    mul[lo_y:hi_y, lo_x:hi_x] *= 1 - arng.uniform(0.35, 0.85) * spot
                else:
                    add[lo_y:hi_y, lo_x:hi_x] += arng.uniform(0.15, 0.45) * spot
            lines = np.zeros((self.ch, self.cw), np.uint8)
            for _ in range(max(1, n_dust // 8)):
                px = arng.uniform(x0 - self.d, x1 + self.d) - self.ox
                py = arng.uniform(y0, y1) - self.oy
                length, angle = arng.uniform(0.5, 4.0) * self.d, arng.uniform(0, np.pi)
                ends = np.array([[px, py], [px + length * np.cos(angle), py + length * np.sin(angle)]])
                pts = np.rint(ends * 16).astype(np.int32)
                level = int(arng.uniform(0.3, 1.0) * 255)
                cv2.line(lines, tuple(pts[0]), tuple(pts[1]), level, 1, cv2.LINE_AA, shift=4)
            add += 0.25 * lines.astype(np.float32) / 255
        tint = np.array([1.0, 0.98, 0.95], np.float32)  # white LEDs, a little cool
        return mul, add[..., None] * tint

    def draw(self, x: np.ndarray, bed: _Bed, exposure: float, vignetting: float,
             from_above: float = 0.0) -> np.ndarray:
        img = self.base.copy()
        cx, cy = x - self.ox, bed.y - self.oy
        r = bed.diam / 2
        smear = self._smear_px(bed.y) if self.app["smear"] > 0 else None
        # Smeared spheres are the time average of sharp ones that never overlap: their
        # averaged colours and coverages add up (painting them over each other would
        # darken where neighbouring streaks meet).
        acc = None if smear is None else (np.zeros_like(img), np.zeros(img.shape[:2], np.float32))
        keep = (cx > -self.d) & (cx < self.cw + self.d)
        for idx in np.array_split(np.flatnonzero(keep), max(1, keep.sum() // 400)):
            self._draw_batch(img, cx[idx], cy[idx], r[idx], bed.heavy[idx], bed.shade[idx],
                             None if smear is None else smear[idx], acc)
        if bed.walls is not None:
            self._draw_bumps(img, bed, acc)
        if acc is not None:
            light, cover = acc
            img = img * (1 - np.clip(cover, 0, 1))[..., None] + light / np.maximum(cover, 1)[..., None]
        img = self._illumination(img, exposure, vignetting, from_above)
        if self.overlay is not None:
            mul, add = self.overlay
            img = np.clip(img * mul[..., None] + add, 0, 1.2).astype(np.float32)
        return img

    def _smear_px(self, y: np.ndarray) -> np.ndarray:
        """Motion-blur length [px] at heights y: the plate's smear, decaying like the shift."""
        height = self.win[3] - self.win[1]
        return self.app["smear"] * self.d * np.exp(-(self.win[3] - y) / (self.delta_over_H * height))

    def _draw_batch(self, img, cx, cy, r, heavy, shade, smear=None, acc=None) -> None:
        colour, alpha, bx, by = self._sprites(cx, cy, r, heavy, self.looks, shade, smear)
        for k in np.random.default_rng(len(cx)).permutation(len(cx)):
            if acc is None:
                _paste(img, colour[k], alpha[k], bx[k], by[k])
            else:
                _accumulate(acc, colour[k], alpha[k], bx[k], by[k])

    def _sprites(self, cx, cy, r, kind, looks, shade, smear=None, visible_side=None):
        """Sprites (colour (m, s, w, 3), alpha (m, s, w), top-left x, y) of spheres at (cx, cy).

        ``kind`` indexes ``looks``; ``smear`` [px] blurs each along x
        (centred); ``visible_side`` (+1 / -1 per sphere) keeps only the half
        above (-1: below) the centre, for the hemispheres on the walls.
        """
        s = int(np.ceil(2 * r.max())) + 4
        pad = 0 if smear is None else 2 * (int(np.ceil(smear.max() / 2)) + 1)
        bx, by = np.floor(cx - (s + pad) / 2).astype(int), np.floor(cy - s / 2).astype(int)
        g = np.arange(s, dtype=np.float32)
        gx = g if pad == 0 else np.arange(s + pad, dtype=np.float32)
        dx = (bx[:, None, None] + gx[None, None, :]) - cx[:, None, None]
        dy = (by[:, None, None] + g[None, :, None]) - cy[:, None, None]
        dx, dy = np.broadcast_arrays(dx, dy)
        dist = np.sqrt(dx * dx + dy * dy)
        alpha = np.clip(r[:, None, None] - dist + 0.5, 0, 1).astype(np.float32)
        if visible_side is not None:
            alpha *= np.clip(0.5 - visible_side[:, None, None] * dy, 0, 1).astype(np.float32)
        colour = np.empty((*dx.shape, 3), np.float32)
        for k, look in enumerate(looks):
            sel = kind == k
            if sel.any():
                colour[sel] = self._shade(dx[sel], dy[sel], r[sel], cx[sel], cy[sel], look)
        colour *= shade[:, None, None, None].astype(np.float32)
        if smear is not None:
            colour, alpha = _smear(colour, alpha, smear)
        return colour, alpha, bx, by

    def _draw_bumps(self, img, bed: _Bed, acc=None) -> None:
        """The hemispheres of the lid and plate: domes of the wall's PLA, the plate's smeared with it."""
        bx, by, bd = bed.walls.centres()
        cx, cy = bed.x_lo + bx - self.ox, by - self.oy
        keep = (cx > -self.d) & (cx < self.cw + self.d)
        if not keep.any():
            return
        plate = bed.walls.on_plate[keep] > 0
        smear = None
        if self.app["smear"] > 0:
            smear = np.where(plate, self.app["smear"] * self.d, 0.0)
        shade = np.where(plate, 0.9, 1.0)  # the plate's bumps sit lower, further from the lamps
        colour, alpha, sx, sy = self._sprites(cx[keep], cy[keep], bd[keep] / 2, np.zeros(plate.size, int),
                                              (WALL_LOOK,), shade, smear, np.where(plate, 1.0, -1.0))
        for k in range(plate.size):
            if acc is None:
                _paste(img, colour[k], alpha[k], sx[k], sy[k])
            else:
                _accumulate(acc, colour[k], alpha[k], sx[k], sy[k])

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
        if look.get("mirror"):
            body = base * self._mirror(nx, ny, nz)[..., None]
        elif look["metal"]:
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

    def _mirror(self, nx, ny, nz) -> np.ndarray:
        """What a polished sphere mirrors along the reflected ray R = 2 (n.v) n - v (v = to the camera).

        The dark lab and the camera behind the view, the bed below, a lit
        ceiling above, and each lamp as a panel of 0.4 rad angular radius
        with a sharp edge.
        """
        rx, ry, rz = 2 * nz * nx, 2 * nz * ny, 2 * nz * nz - 1
        env = 0.06 + 0.06 * np.clip(ry, 0, 1)  # dark lab; the bed below a little lighter
        env = env + 0.5 * np.clip((-ry - 0.05) / 0.75, 0, 1) ** 1.2  # the lit room above
        for lx, ly, lz, power in self.lights:
            ln = np.array([lx, ly, lz]) / np.linalg.norm([lx, ly, lz])
            cos = rx * ln[0] + ry * ln[1] + rz * ln[2]
            env = env + 2.2 * power * np.clip((cos - np.cos(0.4)) / 0.015, 0, 1)
        return env

    def _glass(self, dx, dy, cx, cy, rim, tint) -> np.ndarray:
        """Transparent sphere: the grains behind, inverted and tinted; dark outline."""
        mx = (cx[:, None, None] - 0.55 * dx).astype(np.float32)
        my = (cy[:, None, None] - 0.55 * dy).astype(np.float32)
        m, sh, sw = dx.shape
        seen = cv2.remap(self.behind, mx.reshape(m * sh, sw), my.reshape(m * sh, sw),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).reshape(m, sh, sw, 3)
        ring = np.clip((rim - 0.45) / 0.35, 0, 1)
        body = (0.22 + 1.8 * seen) * tint * (1 - 0.85 * ring[..., None])
        return body + 0.25 * np.exp(-((rim - 0.93) / 0.05) ** 2)[..., None]

    def _illumination(self, img: np.ndarray, exposure: float, vignetting: float,
                      from_above: float = 0.0) -> np.ndarray:
        """Lamps at the sides, lens vignetting and a lamp above (``from_above``): smooth brightness
        over the image."""
        yy, xx = np.mgrid[0:self.ch, 0:self.cw].astype(np.float32)
        u = (xx - self.cw / 2) / (self.cw / 2)
        v = (yy - self.ch / 2) / (self.ch / 2)
        gain = exposure * (1 - vignetting * (u * u + v * v) / 2)
        if from_above > 0:  # the light falls off linearly down the canvas
            gain = gain * (1 - from_above * yy / max(self.ch - 1, 1))
        return np.clip(img * gain[..., None], 0, 1.2).astype(np.float32)


def _paste(img: np.ndarray, colour: np.ndarray, alpha: np.ndarray, x: int, y: int) -> None:
    """Alpha-blend one sprite at (x, y), clipped to the canvas."""
    h, w = img.shape[:2]
    sh, sw = alpha.shape
    x_a, y_a, x_b, y_b = max(x, 0), max(y, 0), min(x + sw, w), min(y + sh, h)
    if x_a >= x_b or y_a >= y_b:
        return
    a = alpha[y_a - y:y_b - y, x_a - x:x_b - x, None]
    region = img[y_a:y_b, x_a:x_b]
    region *= 1 - a
    region += a * colour[y_a - y:y_b - y, x_a - x:x_b - x]


def _accumulate(acc: tuple[np.ndarray, np.ndarray], colour: np.ndarray, alpha: np.ndarray, x: int, y: int) -> None:
    """Add one sprite's light (colour x coverage) and coverage to the accumulators, clipped to the canvas."""
    light, cover = acc
    h, w = cover.shape
    sh, sw = alpha.shape
    x_a, y_a, x_b, y_b = max(x, 0), max(y, 0), min(x + sw, w), min(y + sh, h)
    if x_a >= x_b or y_a >= y_b:
        return
    a = alpha[y_a - y:y_b - y, x_a - x:x_b - x]
    cover[y_a:y_b, x_a:x_b] += a
    light[y_a:y_b, x_a:x_b] += a[..., None] * colour[y_a - y:y_b - y, x_a - x:x_b - x]


def _smear(colour: np.ndarray, alpha: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Motion blur: each sprite averaged over a horizontal move of ``length`` [px] centred on it.

    colour (m, s, w, 3), alpha (m, s, w), length (m,). The premultiplied
    colour and the coverage are box-filtered along x (exact for a sprite
    constant over each pixel: differences of the running sum, read at
    fractional positions), so a sphere becomes a semi-transparent streak
    whose centre is the sphere's mid-exposure position.
    """
    m, s, w = alpha.shape
    stack = np.concatenate([colour * alpha[..., None], alpha[..., None]], axis=-1).astype(np.float64)
    run = np.concatenate([np.zeros((m, s, 1, 4)), np.cumsum(stack, axis=2)], axis=2)  # knot k at x = k - 0.5
    length = np.maximum(np.asarray(length, dtype=float), 1e-3)
    x = np.arange(w, dtype=float)

    def at(u: np.ndarray) -> np.ndarray:  # running sum at positions u (m, w), linear between knots
        q = np.clip(u + 0.5, 0, w)
        k = np.minimum(np.floor(q).astype(int), w - 1)
        f = (q - k)[:, None, :, None]
        lo = np.take_along_axis(run, np.broadcast_to(k[:, None, :, None], (m, s, w, 4)), axis=2)
        hi = np.take_along_axis(run, np.broadcast_to(k[:, None, :, None] + 1, (m, s, w, 4)), axis=2)
        return lo * (1 - f) + hi * f

    half = length[:, None] / 2
    out = (at(x[None] + half) - at(x[None] - half)) / length[:, None, None, None]
    a = np.clip(out[..., 3], 0, 1)
    col = out[..., :3] / np.maximum(out[..., 3:], 1e-6)
    return col.astype(np.float32), a.astype(np.float32)


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
    """Solid densities [kg/m^3] of the two materials (looks name theirs), from the model's table."""
    try:
        # lazy on purpose: rendering frames must run without the compiled solver
        from granseg.model import MATERIALS

        table = {k.lower(): float(v) for k, v in MATERIALS.items()}
        names = [MATERIAL_LOOKS.get(m.lower(), {}).get("material", m).lower() for m in (heavy, light)]
        return table[names[0]], table[names[1]]
    except (ImportError, KeyError, AttributeError):
        # The model (Rust extension) is not available: nominal placeholders,
        # heavier first. Pass experiment={"rho_h": ..., "rho_l": ...} to set them.
        return 2.0e3, 1.0e3


def _write(result: RenderedFrames, out: Path, jpeg_quality: int | None, force: bool) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    ext = ".png" if jpeg_quality is None else ".jpg"
    params = [] if jpeg_quality is None else [cv2.IMWRITE_JPEG_QUALITY, 100]
    paths = []
    for i, img in enumerate(result.images):
        p = out / f"frame_{i:04d}{ext}"
        with atomic_path(p, force=force) as tmp:
            if not cv2.imwrite(cv2_path(tmp), img, params):
                raise OSError(f"{p}: could not write image")
        paths.append(p)
    paths.append(save_json(out / "experiment.json", result.experiment, force=force))
    return paths


def _video(result: RenderedFrames, app: dict[str, Any], out_dir, force: bool) -> tuple[list[np.ndarray], list[Path]]:
    """Encode the frames as a lossy video; return the decoded frames and the files written."""
    import tempfile

    if out_dir is None:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "video.mp4"
            _encode(result.images, path, app["video"], app["bitrate"])
            return _decode(path, len(result.images)), []
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "video.mp4"
    with atomic_path(path, force=force) as tmp:  # tmp ends in .mp4: the encoders pick the container by it
        _encode(result.images, tmp, app["video"], app["bitrate"])
    images = _decode(path, len(result.images))
    return images, [path, save_json(out / "experiment.json", result.experiment, force=force)]


def _encode(images: list[np.ndarray], path: Path, codec: str, bitrate: float | None, key_every: int = 15) -> None:
    """``images`` as a video at ``path``: ``codec`` "mp4v" with no ``bitrate`` by OpenCV (a key frame
    every 12), else by PyAV ("h264" or MPEG-4 at ``bitrate``), a key frame every ``key_every``
    frames at most (15: every half second, as a GoPro)."""
    h, w = images[0].shape[:2]
    if codec == "mp4v" and bitrate is None:
        writer = cv2.VideoWriter(cv2_path(path), cv2.VideoWriter_fourcc(*"mp4v"), VIDEO_PLAYBACK_FPS, (w, h))
        if not writer.isOpened():
            raise OSError(f"{path}: OpenCV cannot write MPEG-4 (mp4v) video here")
        for img in images:
            writer.write(img)
        writer.release()
        return
    try:
        import av
    except ImportError:
        what = "H.264 video" if codec == "h264" else "an MPEG-4 video at a chosen bitrate"
        raise ImportError(f"{what} needs PyAV (pip install av); video='mp4v' without "
                          "video_bitrate needs only OpenCV") from None
    if bitrate is None:
        bitrate = VIDEO_BITS_PER_PIXEL * w * h * VIDEO_PLAYBACK_FPS
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264" if codec == "h264" else "mpeg4", rate=int(VIDEO_PLAYBACK_FPS))
        stream.width, stream.height, stream.pix_fmt = w + (w % 2), h + (h % 2), "yuv420p"
        stream.bit_rate = int(bitrate)
        stream.codec_context.gop_size = key_every
        if codec == "h264":
            stream.options = {"preset": "medium", "threads": "1"}
        for img in images:
            if w % 2 or h % 2:  # 4:2:0 needs even sizes: repeat the last column / row
                img = cv2.copyMakeBorder(img, 0, h % 2, 0, w % 2, cv2.BORDER_REPLICATE)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _decode(path: Path, n: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(cv2_path(path))
    images = []
    try:
        while len(images) < n:
            ok, img = cap.read()
            if not ok:
                break
            images.append(img)
    finally:
        cap.release()
    if len(images) != n:
        raise OSError(f"{path}: wrote {n} frames but OpenCV reads back {len(images)}")
    return images


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
