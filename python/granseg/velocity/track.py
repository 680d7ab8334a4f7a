"""Velocity profiles from footage: spheres found, linked between frames, displacements per layer.

What the paper did by hand in ImageJ, per recording:

1. **Find** the spheres of every frame with the frame pipeline
   (:func:`granseg.measure.pipeline.detect_frames`): centres in undistorted pixels,
   so the lens is already corrected.
2. **Guess** each layer's displacement per frame from the peak of the histogram of
   horizontal offsets between the spheres of consecutive frames (same layer, within
   :data:`MAX_STEP` diameters): every sphere contributes one offset at the true
   displacement, its neighbours spread theirs over a diameter.
3. **Link** with trackpy in a frame that moves with that guess (x - u(y) i), where
   every sphere is nearly still, so a small search radius (:data:`SEARCH`
   diameters) is unambiguous even where the plate moves half a diameter per frame.
4. **Measure** per layer the summed displacement of the tracks over their summed
   duration. A track's displacement telescopes to its last minus its first position,
   so each layer gets the longest lag its grains allow: long where the bed creeps
   (tracks last the whole recording), short where it is fast (grains cross the window
   in a few frames); the positions' noise enters twice per track, not twice per frame.
5. **Unroll the wall**: the camera sees the outer wall, a cylinder of radius R, from
   outside; a sphere at arc length s from the window's centre appears at R sin(s / R),
   so arc lengths are R asin(x / R) (x from the window's centre). Without it the
   speeds near the window's sides come out low by up to 1 - cos(s / R) (4 % at the
   side of a 9-diameter window on the paper's 0.19 m cell).

Frame k was filmed at k / fps, unless a video's own time stamps stray from an even rate (a
camera slowing down in dim light, as phones do) and the video plays at about the rate it was
filmed: then the stamps are the frames' times, for the guess, the co-moving frame and the
durations alike (:func:`_clock`, measure.pipeline.frame_times).

Errors: the recording is cut into :data:`BLOCKS` consecutive time blocks; a layer's
standard error is the spread of its block velocities over sqrt(blocks), which holds
when the bed's speed and the positions' noise are correlated within a block but not
across blocks. Several recordings (any frame rates) join per layer by inverse-variance
weights, with the errors scaled up by sqrt(chi^2 / dof) when the recordings disagree
beyond them. A layer moving more than :data:`MAX_STEP` diameters per frame in a
recording is left out of that recording (its links cannot be trusted); one whose grains
barely move between frames gets a large error and little weight.

The fit takes neighbouring layers' errors as correlated (:data:`LAYER_CORRELATION`): the
window shows a few grains per layer, and those of adjacent layers deviate from their bands
together (a slow cluster spans layers), which errors taken as independent understate.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from granseg.constants import D_P
from granseg.errors import short_repr
from granseg.measure.experiment import load_experiment
from granseg.measure.layers import height
from granseg.measure.pipeline import Detected, detect_frames
from granseg.measure.sources import open_frames
from granseg.model import _finite, defaults
from granseg.velocity.profile import VelocityProfile

__all__ = ["BLOCKS", "LAYER_CORRELATION", "MAX_STEP", "SEARCH", "Recording", "measure_velocity", "track_recording"]

log = logging.getLogger(__name__)

#: Largest displacement per frame [diameters] a layer may have for its links to be trusted.
MAX_STEP = 0.6
#: Search radius of the linking in the co-moving frame [diameters].
SEARCH = 0.3
#: Time blocks a recording is cut into for the errors.
BLOCKS = 8
#: Fewest blocks with data for a layer's error.
MIN_BLOCKS = 3
#: Bin width of the offset histogram [diameters].
BIN = 0.02
#: Correlation of neighbouring layers' errors in the shear-band fit (phi^k at k layers apart).
#: Chosen on the renderer's tuning beds (seeds 1-4, delta/H 0.12-0.30, 100 fps), where the
#: layers' deviations from the truth, in their errors, correlate 0.34 one layer apart and the
#: fit's errors in its standard errors level off from 0.5 up (BENCHMARKS.md, "Neighbouring
#: layers' errors").
LAYER_CORRELATION = 0.5


@dataclass
class Recording:
    """One recording's tracks and per-layer result (SI units).

    tracks: (m, 6) array of frame, track id, arc position s [m], height z [m], and the
    centre x, y [undistorted px] (for previews);
    v, v_err, z, n: per layer speed [m/s] (NaN where left out), its error, the mean height
    of the grains measured [m] and the number of tracked grain-frames; step: the guessed
    displacement per frame [diameters]; notes: what was left out and why.
    """

    source: str
    fps: float
    tracks: np.ndarray
    v: np.ndarray
    v_err: np.ndarray
    z: np.ndarray
    n: np.ndarray
    step: np.ndarray
    notes: list[str]
    detected: Detected


def _wall_radius(exp_raw: dict[str, Any]) -> float:
    """Radius [m] of the wall the camera looks through: experiment.json's ``wall_radius``
    (0: a flat wall), else docs/model.md's outer cylinder, D_out / 2."""
    r = exp_raw.get("wall_radius")
    if r is None:
        return defaults()["D_out"] / 2
    if not isinstance(r, (int, float)) or not np.isfinite(r) or r < 0:
        raise ValueError(f"experiment.json: field 'wall_radius': expected a radius >= 0 m (0 = flat), got {r!r}")
    return float(r)


def _raw_experiment(det: Detected) -> dict[str, Any]:
    import json

    return json.loads(det.experiment.path.read_text(encoding="utf-8"))


def _frames_table(det: Detected) -> np.ndarray:
    """(m, 3): frame index, x, y [undistorted px] of every sphere found."""
    rows = [np.column_stack([np.full(s.x.size, i), s.x, s.y]) for i, s in enumerate(det.spheres) if s is not None]
    return np.concatenate(rows) if rows else np.zeros((0, 3))


def _guess_steps(table: np.ndarray, layer: np.ndarray, n_layers: int, d: float, clock: np.ndarray,
                 max_pairs: int = 400) -> np.ndarray:
    """Each layer's displacement per frame [px]: the peak of the histogram of the offsets between
    consecutive frames over their interval (``clock``: each frame's time in frames, :func:`_clock`),
    of spheres of the same layer, within MAX_STEP diameters per frame across and a quarter diameter
    up or down. NaN where no frame pair shows a clear peak."""
    frames = np.unique(table[:, 0]).astype(int)
    pairs = [f for f in frames if f + 1 in set(frames)]
    pairs = pairs[:: max(1, len(pairs) // max_pairs)]
    edges = np.arange(-MAX_STEP - BIN / 2, MAX_STEP + BIN, BIN) * d
    hist = np.zeros((n_layers, edges.size - 1))
    by_frame = {f: np.flatnonzero(table[:, 0] == f) for f in frames}
    for f in pairs:
        a, b = by_frame[f], by_frame[f + 1]
        dx = (table[b, 1][None, :] - table[a, 1][:, None]) / (clock[f + 1] - clock[f])
        dy = table[b, 2][None, :] - table[a, 2][:, None]
        near = (np.abs(dy) < 0.25 * d) & (np.abs(dx) <= MAX_STEP * d)
        ia, _ = np.nonzero(near)
        for j in range(n_layers):
            sel = layer[a][ia] == j
            if sel.any():
                hist[j] += np.histogram(dx[near][sel], bins=edges)[0]
    centres = 0.5 * (edges[1:] + edges[:-1])
    steps = np.full(n_layers, np.nan)
    for j in range(n_layers):
        h = np.convolve(hist[j], [0.25, 0.5, 0.25], mode="same")
        if h.max() <= 0:
            continue
        k = int(np.argmax(h))
        # the true offset is a sharp peak, well above the histogram's mean level
        if h[k] < 3 * h.mean():
            continue
        near_peak = slice(max(k - 3, 0), k + 4)
        steps[j] = float(np.average(centres[near_peak], weights=hist[j][near_peak] + 1e-12))
    # layers without a clear peak take their neighbours' value (the profile is smooth)
    ok = np.isfinite(steps)
    if ok.any() and not ok.all():
        steps[~ok] = np.interp(np.flatnonzero(~ok), np.flatnonzero(ok), steps[ok])
    return steps


def _link(table: np.ndarray, steps_px: np.ndarray, n_layers: int, window, d: float, clock: np.ndarray
          ) -> np.ndarray:
    """Track ids of the rows of ``table`` (-1: not linked), by trackpy in the co-moving frame
    (``clock``: each frame's time in frames, :func:`_clock`)."""
    import pandas as pd
    import trackpy

    trackpy.quiet()
    zc = np.arange(n_layers) + 0.5
    u = np.interp(height(table[:, 2], window, n_layers), zc, steps_px)
    frame = table[:, 0].astype(int)
    df = pd.DataFrame({"x": table[:, 1] - u * clock[frame], "y": table[:, 2], "frame": frame})
    with warnings.catch_warnings():
        # trackpy 0.7 uses pandas' deprecated ``inplace=`` (a warning per call under pandas 3)
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", FutureWarning)
        linked = trackpy.link(df, search_range=SEARCH * d, memory=0, adaptive_stop=0.05 * d, adaptive_step=0.9)
    return linked["particle"].to_numpy()


def _unroll(x_px: np.ndarray, window, scale: float, radius: float) -> np.ndarray:
    """Arc position s [m] along the wall from the window's centre, of image columns x [px]."""
    xm = (x_px - 0.5 * (window[0] + window[2])) * scale
    if radius <= 0:
        return xm
    return radius * np.arcsin(np.clip(xm / radius, -1.0, 1.0))


def _segments(tracks: np.ndarray, key: np.ndarray, D: float, n_layers: int) -> tuple[np.ndarray, ...]:
    """Per segment (the rows sharing ``key``, in frame order; one-point segments dropped):
    layer of its mean height, displacement [m], duration (in the units of the first column:
    frames), summed heights [m],
    points, and the row of ``tracks`` it starts at."""
    order = np.lexsort((tracks[:, 0], key))
    frame, s, z, key = tracks[order, 0], tracks[order, 2], tracks[order, 3], key[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], key.size] - 1
    keep = ends > starts
    zsum = np.add.reduceat(z, starts)[keep] if starts.size else np.zeros(0)
    starts, ends = starts[keep], ends[keep]
    points = ends - starts + 1
    layer = np.clip(np.floor(zsum / points / D).astype(int), 0, n_layers - 1)
    return layer, s[ends] - s[starts], frame[ends] - frame[starts], zsum, points, order[starts]


def _layer_speeds(tracks: np.ndarray, clock: np.ndarray, fps: float, n_layers: int, D: float
                  ) -> tuple[np.ndarray, ...]:
    """Per layer: speed [m/s], its error, mean height [m] and tracked grain-frames (``clock``: each
    frame's time in frames at ``fps``, :func:`_clock`).

    The error is the larger of two: the spread of the speeds of BLOCKS consecutive time
    blocks (the bed's unsteadiness and the positions' noise), and the spread over the
    tracks, each a cluster of its own (a creeping layer shows the same few grains all
    recording long, and each has its own mean speed: the wall samples the band)."""
    frame, tid = tracks[:, 0].astype(int), tracks[:, 1]
    timed = tracks.copy()  # the segments' durations in frames of the clock
    timed[:, 0] = clock[frame]
    block = np.minimum((timed[:, 0] * BLOCKS / (clock[-1] + 1)).astype(int), BLOCKS - 1)
    # one segment per (track, block): its displacement telescopes to last - first
    layer, disp, dur, zsum, points, first = _segments(timed, tid * BLOCKS + block, D, n_layers)
    seg_block = block[first]
    D_b = np.zeros((BLOCKS, n_layers))
    T_b = np.zeros((BLOCKS, n_layers))
    np.add.at(D_b, (seg_block, layer), disp)
    np.add.at(T_b, (seg_block, layer), dur / fps)
    count = np.bincount(layer, points, minlength=n_layers)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = D_b.sum(0) / T_b.sum(0)
        z_mean = np.bincount(layer, zsum, minlength=n_layers) / count
        v_blocks = np.where(T_b > 0, D_b / T_b, np.nan)
    err_block = np.full(n_layers, np.nan)
    for j in range(n_layers):
        vb = v_blocks[:, j][np.isfinite(v_blocks[:, j])]
        if vb.size >= MIN_BLOCKS:
            err_block[j] = np.std(vb, ddof=1) / np.sqrt(vb.size)
    t_layer, t_disp, t_dur, *_ = _segments(timed, tid, D, n_layers)
    err_track = np.full(n_layers, np.nan)
    for j in range(n_layers):
        sel = (t_layer == j) & (t_dur > 0)
        g = int(sel.sum())
        if g >= MIN_BLOCKS and np.isfinite(v[j]):
            resid = t_disp[sel] - v[j] * t_dur[sel] / fps
            err_track[j] = np.sqrt(g / (g - 1) * np.sum(resid**2)) / (t_dur[sel].sum() / fps)
    return v, np.fmax(err_block, err_track), z_mean, count


def _clock(det: Detected) -> tuple[np.ndarray, str | None]:
    """Each frame's time in frames at ``det.fps``: its place in the recording, or, where a video's
    own time stamps stray from an even rate and tell when it was filmed (pipeline.frame_times: a
    phone slowing its rate in dim light), the stamps (times fps); and a note where they stray."""
    if det.times.seconds is None:  # the index itself, not (k / fps) x fps, which rounds
        return np.arange(len(det.spheres), dtype=float), det.times.note
    return det.times.row_seconds(len(det.spheres), det.fps) * det.fps, det.times.note


def track_recording(path: str | os.PathLike, *, D_p: float = D_P, prior: np.ndarray | None = None,
                    workers: int | None = None, progress: bool = True) -> Recording:
    """Tracks and per-layer speeds of one recording (frames directory or video with
    ``experiment.json``); see the module doc for the method.

    ``prior``: per-layer speeds [m/s] already measured on this bed (by a faster camera;
    NaN where unknown). Where given it replaces the histogram's guess: at a low frame rate
    a fast layer moves more than the histogram's range per frame and would alias."""
    det = detect_frames(path, workers=workers, progress=progress)
    exp = det.experiment
    d, window = exp.particle_diameter_px, exp.window
    n_layers = max(1, int(round((window[3] - window[1]) / d)))
    scale = D_p * n_layers / (window[3] - window[1])  # m per px, from the window's height
    radius = _wall_radius(_raw_experiment(det))
    table = _frames_table(det)
    layer = np.clip(np.floor(height(table[:, 2], window, n_layers)).astype(int), 0, n_layers - 1)
    clock, uneven = _clock(det)
    notes = [] if uneven is None else [f"{Path(path).name}: {uneven}"]
    steps = _guess_steps(table, layer, n_layers, d, clock)
    if prior is not None:
        known = np.isfinite(prior)
        steps = np.where(known, np.asarray(prior) / det.fps / scale, steps)
    if not np.isfinite(steps).any():
        raise ValueError(f"{exp.path.parent}: no layer shows a consistent displacement between frames "
                         f"(faster than {MAX_STEP} diameters per frame, or too few spheres found)")
    ids = _link(table, np.nan_to_num(steps), n_layers, window, d, clock)
    z = height(table[:, 2], window, n_layers) * D_p
    tracks = np.column_stack([table[:, 0], ids, _unroll(table[:, 1], window, scale, radius), z,
                              table[:, 1], table[:, 2]])
    v, v_err, z_mean, count = _layer_speeds(tracks, clock, det.fps, n_layers, D_p)
    longest = float(np.max(np.diff(clock), initial=1.0))  # the longest interval between frames [frames]
    fast = ((np.abs(steps) * longest / d > MAX_STEP * 0.9)
            | (np.abs(v) * longest / det.fps / scale / d > MAX_STEP * 0.9))
    if fast.any():
        notes.append(f"{Path(path).name}: layers {', '.join(str(j + 1) for j in np.flatnonzero(fast))} move "
                     f"about {MAX_STEP} diameters per frame or more at {det.fps:g} fps: left out")
        v[fast], v_err[fast] = np.nan, np.nan
    return Recording(str(path), det.fps, tracks, v, v_err, z_mean, count, steps / d, notes, det)


def join(recordings: Sequence[Recording]) -> tuple[np.ndarray, ...]:
    """Per layer, the recordings' inverse-variance mean speed, its error (scaled by
    sqrt(chi^2 / dof) where they disagree), mean height and grain-frames."""
    v = np.array([r.v for r in recordings])
    e = np.array([r.v_err for r in recordings])
    zs = np.array([r.z for r in recordings])
    n = np.array([r.n for r in recordings]).sum(0)
    ok = np.isfinite(v) & np.isfinite(e) & (e > 0)
    w = np.where(ok, 1.0 / np.where(ok, e, 1.0) ** 2, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (w * np.where(ok, v, 0)).sum(0) / w.sum(0)
        err = 1.0 / np.sqrt(w.sum(0))
        chi2 = (w * (np.where(ok, v, 0) - mean) ** 2).sum(0)
        dof = ok.sum(0) - 1
        inflate = np.where(dof > 0, np.sqrt(np.maximum(chi2 / np.maximum(dof, 1), 1.0)), 1.0)
        z = (w * np.where(ok, zs, 0)).sum(0) / w.sum(0)
    return mean, err * inflate, z, n


def _frame_rate_of(path: str | os.PathLike) -> float:
    """A recording's frame rate [1/s] (experiment.json's, else the video's)."""
    source, exp_path = open_frames(path)
    fps = load_experiment(exp_path).fps or source.fps
    if not fps or fps <= 0:
        raise ValueError(f"{exp_path}: missing field 'fps' (frames per second)")
    return float(fps)


def _length(name: str, value: Any) -> float:
    """``value`` [m] as a finite float > 0, else a ValueError naming ``name``."""
    v = _finite(value, f"measure_velocity: {name} =")
    if v <= 0:
        raise ValueError(f"measure_velocity: {name} = {short_repr(value)} m must be > 0")
    return v


def measure_velocity(recordings: str | os.PathLike | Sequence[str | os.PathLike], *, D_p: float = D_P,
                     H: float | None = None, workers: int | None = None, progress: bool = True
                     ) -> tuple[VelocityProfile, list[Recording]]:
    """The streamwise velocity profile at the wall of one bed from one or several recordings
    (frames directories or videos with ``experiment.json``, at any frame rates), with the
    shear-band fit; also each recording's tracks (for previews).

    ``D_p`` [m] is the grains' diameter (the window's layers are one diameter high); ``H``
    [m] the bed height delta is scaled by (default: the window's layers times D_p).
    """
    paths = [recordings] if isinstance(recordings, (str, os.PathLike)) else list(recordings)
    if not paths:
        raise ValueError("measure_velocity: no recording given")
    # both lengths are checked before any recording is tracked, which takes minutes
    D_p = _length("D_p", D_p)
    if H is not None:
        H = _length("H", H)
    # the fastest camera first: its profile guides the linking of the slower ones
    paths.sort(key=lambda p: -_frame_rate_of(p))
    recs: list[Recording] = []
    for i, p in enumerate(paths):
        log.info("velocity: recording %d of %d: %s", i + 1, len(paths), p)
        prior = join(recs)[0] if recs else None
        recs.append(track_recording(p, D_p=D_p, prior=prior, workers=workers, progress=progress))
    v, v_err, z, n = join(recs)
    sign = np.sign(v[np.isfinite(v)][0]) if np.isfinite(v).any() else 1.0
    v = sign * v  # speeds along the plate's motion
    n_layers = v.size
    height_m = H if H is not None else n_layers * D_p
    exp = recs[0].detected.experiment
    notes = [note for r in recs for note in r.notes]
    missing = np.flatnonzero(~np.isfinite(v) | ~np.isfinite(v_err))
    if missing.size:
        notes.append(f"no speed for layer(s) {', '.join(str(j + 1) for j in missing)} in any recording")
        z = np.where(np.isfinite(z), z, (np.arange(n_layers) + 0.5) * D_p)
    if np.isfinite(v).sum() < 3:
        raise ValueError("measure_velocity: fewer than 3 layers have a speed; record at other frame rates")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        prof = VelocityProfile.fitted(z, v, v_err, height_m, layer_correlation=LAYER_CORRELATION,
                                      n=n, conditions=exp.metadata(),
                                      sources=[r.source for r in recs], notes=notes)
    return prof, recs
