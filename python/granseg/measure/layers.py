"""Bin sphere centres into the window's horizontal layers (layer 0 at the bottom); how far apart they lie."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from granseg.constants import N_LAYERS

__all__ = ["N_LAYERS", "WALL_CLEARANCE", "across", "clear_of_walls", "followed_window", "height", "in_window", "layer_index", "layer_counts",
           "nearest_distances", "nearest_spacing", "row_window"]

# A free sphere's centre lies at least half a diameter from the lid and the
# plate (more between the bumps). The hemispheres fixed to both walls, one
# diameter across, are centred on the wall line: seen from the side, their
# outline fit puts them within 0.30 d of it (rendered apparatus looks, seeds
# 9 and 10, up to 0.30 d under the polished steel of S-POM in MPEG-4), while
# the spheres nearest a wall were found at 0.47 d or more. 0.38 d splits the
# two and leaves 0.1 d of slack for a window drawn slightly off the wall line.
WALL_CLEARANCE = 0.38


def in_window(x: np.ndarray, y: np.ndarray, window: tuple[float, float, float, float]) -> np.ndarray:
    """True where the centre (x, y) [undistorted px] lies in window = (x0, y0, x1, y1), half-open."""
    x0, y0, x1, y1 = window
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def clear_of_walls(y: np.ndarray, window: tuple[float, float, float, float], particle_diameter_px: float,
                   clearance: float = WALL_CLEARANCE) -> np.ndarray:
    """True where the centre height y [undistorted px] is at least ``clearance`` diameters from lid and plate.

    The lid is at the window's y0, the plate at its y1.
    """
    _, y0, _, y1 = window
    gap = clearance * particle_diameter_px
    y = np.asarray(y, dtype=float)
    return (y >= y0 + gap) & (y <= y1 - gap)


def height(y: np.ndarray, window: tuple[float, float, float, float], n_layers: int = N_LAYERS) -> np.ndarray:
    """Height of centres y [undistorted px] above the bottom wall (y1), in layer heights (diameters)."""
    _, y0, _, y1 = window
    return (y1 - np.asarray(y, dtype=float)) / ((y1 - y0) / n_layers)


def followed_window(window: tuple[float, float, float, float], down: float, rise: float,
                    n_layers: int = N_LAYERS) -> tuple[float, float, float, float]:
    """``window`` with both its lines moved ``down`` layer heights down the image (negative: up), and
    its lid line (y0) ``rise`` layer heights up besides (negative: down): the lines of a row whose
    view had moved and whose lid had risen against the plate (quality.wall_follow)."""
    x0, y0, x1, y1 = window
    layer = (y1 - y0) / n_layers
    return x0, y0 + (down - rise) * layer, x1, y1 + down * layer


def row_window(window: tuple[float, float, float, float], follow: np.ndarray | None,
               i: int) -> tuple[float, float, float, float]:
    """The window map row ``i`` is counted in: ``window``, or with ``follow`` ((n_t, 2) moves [d],
    quality.wall_follow) its lines moved as that row followed the walls (:func:`followed_window`)."""
    return window if follow is None else followed_window(window, *follow[i])


def across(x: np.ndarray, window: tuple[float, float, float, float]) -> np.ndarray:
    """Where centres x [undistorted px] lie across the window: -1 at its left side, 1 at its right."""
    x0, _, x1, _ = window
    return (2.0 * np.asarray(x, dtype=float) - (x0 + x1)) / (x1 - x0)


def layer_index(y: np.ndarray, window: tuple[float, float, float, float], n_layers: int = N_LAYERS) -> np.ndarray:
    """Layer of each centre height y [px]: 0 for the bottom layer (next to y1), n_layers - 1 under the lid."""
    return np.clip(np.floor(height(y, window, n_layers)).astype(int), 0, n_layers - 1)


def layer_counts(x: np.ndarray, y: np.ndarray, heavy: np.ndarray,
                 window: tuple[float, float, float, float], n_layers: int = N_LAYERS) -> tuple[np.ndarray, np.ndarray]:
    """Spheres and heavy spheres whose centre is in each layer: two (n_layers,) int arrays."""
    inside = in_window(x, y, window)
    j = layer_index(y[inside], window, n_layers)
    n = np.bincount(j, minlength=n_layers)
    nh = np.bincount(j[np.asarray(heavy, dtype=bool)[inside]], minlength=n_layers)
    return n, nh


def nearest_distances(centres: np.ndarray, beside: np.ndarray | None = None) -> np.ndarray:
    """The distance [px] from each of ``centres`` (k, 2) to the nearest other sphere, among them and
    ``beside`` (j, 2; neighbours not asked about themselves); NaN where there is none."""
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    known = centres if beside is None else np.concatenate([centres, np.asarray(beside, dtype=float).reshape(-1, 2)])
    if len(known) < 2:
        return np.full(len(centres), np.nan)
    return cKDTree(known).query(centres, k=2)[0][:, 1]


def nearest_spacing(centres: np.ndarray, beside: np.ndarray | None = None) -> float:
    """The median of :func:`nearest_distances` [px]; NaN where there is none.

    Spheres at a wall touch their neighbours, so in a packed bed this is about a diameter."""
    distances = nearest_distances(centres, beside)
    return float(np.median(distances)) if len(distances) and np.isfinite(distances).all() else float("nan")
