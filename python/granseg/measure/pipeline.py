"""Frames or video -> concentration map: ``granseg.analyze``."""

from __future__ import annotations

import logging
import os
import warnings
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from granseg._io import atomic_path, check_creatable, check_writable
from granseg.constants import D_P
from granseg.errors import short_repr
from granseg.maps import moving_average, save_map
from granseg.measure.camera import Undistorter, reduce_frame
from granseg.measure.classify import (
    MARGIN,
    MaterialClasses,
    blur_test,
    classify_by_ranges,
    disk_rises,
    learn_classes,
    learn_spots,
    smeared_images,
    sphere_features,
)
from granseg.measure.detect import INSIDE_RADII, Templates, _near, detect_particles, learn_templates
from granseg.measure.experiment import Experiment, load_experiment
from granseg.measure.exposure import Exposure, bed_level, survey, survey_indices
from granseg.measure.layers import (
    N_LAYERS,
    across,
    clear_of_walls,
    followed_window,
    height,
    in_window,
    layer_counts,
    layer_index,
    row_window,
)
from granseg.measure.outline import class_shift
from granseg.measure.preview import check_previews, write_previews
from granseg.measure.quality import (
    FRAME_TIMES_SHARE,
    LID_MOVE_QUANTILE,
    WALL_LINE_BAND,
    Quality,
    QualityWarning,
    assess,
    level_reading,
    spacing_across_view,
    sphere_spacing,
    vacancies,
    wall_follow,
    wall_lines,
)
from granseg.measure.sources import (
    BadFrame,
    FrameDirectory,
    VideoFrames,
    check_size,
    open_frames,
)
from granseg.measure.wall import remove_wall_glare

__all__ = ["Analysis", "BadFrameWarning", "GreyFramesWarning", "Detected", "FrameSpheres", "analyze", "detect_frames", "write_detections"]

log = logging.getLogger(__name__)

# The middle half of the frames' gaps between the classes' heights on the plate within which the
# gap is taken off the plate's reading (_plate_class_gap): 0.004-0.026 d on the flat 2-D scenes
# (tuning seeds 7-8), 0.19-0.34 d on the bumpy ones.
PLATE_GAP_SPREAD = 0.05


class BadFrameWarning(UserWarning):
    """A frame could not be analysed; its row of the map is NaN."""


class GreyFramesWarning(UserWarning):
    """The frames carry no colour (a monochrome camera, or a grey export): the classes rest on
    brightness, gloss and texture alone."""


@dataclass
class FrameSpheres:
    """Spheres found in one frame's window.

    x, y, r: centre and radius [undistorted px]; score: correlation with the
    template; features: appearance (classify.FEATURES; (m, 0) from detect_frames); heavy, p_heavy: the
    class and its probability (p_heavy None with explicit colour ranges);
    wall: detections left out as hemispheres of the lid or plate (count);
    glare: the most light the wall's reflections added [grey levels], taken off;
    gain: the frame's exposure relative to the first frame's (measure.exposure);
    gain_taken_off: whether it was divided out (the run's gain strays by more
    than DRIFT_LIMIT);
    settle: how far [px] the outline fit's last iteration moved each centre;
    placed: per way of placing a sphere other than by its outline, whether
    each sphere was placed so (:meth:`granseg.measure.templates.Templates.placed`:
    where its template matches best, a material learned from the other's
    matches; its x by a circle of the nominal size, under side lamps);
    beside: centres (k, 2) found beyond the window's left and right sides, in
    its rows and clear of lid and plate (not counted; the vacancies check
    looks up to the sides with them), looked for up to reach = (left, right)
    [px] beyond them (0 where the image does not go on); wall_y, wall_x: the
    centres [undistorted px] of the detections left out as hemispheres of
    the lid or plate (``wall`` of them), which the window_lines check reads;
    at_walls: those detections whole, described as the counted ones are (kept
    only for analyze's ``follow_walls``, else None), which a window that
    follows the walls tells from spheres again (:func:`_split_at_walls`).
    """

    x: np.ndarray
    y: np.ndarray
    r: np.ndarray
    score: np.ndarray
    features: np.ndarray
    settle: np.ndarray
    wall: int = 0
    glare: float = 0.0
    gain: float = 1.0
    gain_taken_off: bool = False
    heavy: np.ndarray | None = None
    p_heavy: np.ndarray | None = None
    placed: dict[str, np.ndarray] = field(default_factory=dict)
    beside: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    reach: tuple[float, float] = (0.0, 0.0)
    wall_y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    wall_x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    at_walls: FrameSpheres | None = None


@dataclass
class Analysis:
    """Result of :func:`analyze`: the map arrays and what happened on the way.

    c, c_raw: (n_t, 15) heavy share (smoothed / raw; NaN = no reading);
    n, n_heavy: (n_t, 15) counts; t [s]; z [m]; smoothing_frames;
    spheres: per frame, FrameSpheres or None for a bad frame;
    bad_frames: list of (frame name, problem); out: the map file written (or None);
    quality: the checks of :mod:`granseg.measure.quality` (also stored in the map);
    classes: the learned heavy / light classifier (None with colour ranges);
    first, every: the map's row i is the recording's frame first + i x every (first > 0 where the
    recording started before the plate, a negative ``t0``);
    follow: (n_t, 2) how far [d] each row's window was moved with the walls (the view's move down,
    the lid's rise against the plate; quality.wall_follow), or None: every row counted in the
    experiment's window.
    """

    c: np.ndarray
    c_raw: np.ndarray
    n: np.ndarray
    n_heavy: np.ndarray
    t: np.ndarray
    z: np.ndarray
    smoothing_frames: int
    experiment: Experiment
    frame_names: list[str]
    spheres: list[FrameSpheres | None]
    bad_frames: list[tuple[str, str]] = field(default_factory=list)
    out: Path | None = None
    previews: list[Path] = field(default_factory=list)
    quality: Quality | None = None
    classes: MaterialClasses | None = None
    detections: Path | None = None
    first: int = 0
    every: int = 1
    follow: np.ndarray | None = None

    def window_of(self, i: int) -> tuple[float, float, float, float]:
        """The window map row ``i`` was counted in: the experiment's, or with ``follow`` (analyze's
        ``follow_walls``) its lines moved with the walls (layers.followed_window)."""
        return row_window(self.experiment.window, self.follow, i)


def analyze(
    path: str | os.PathLike,
    *,
    out: str | os.PathLike | None = None,
    smooth: int = 5,
    smooth_seconds: float | None = None,
    every: int = 1,
    every_seconds: float | None = None,
    preview: str | os.PathLike | None = None,
    preview_count: int = 6,
    force: bool = False,
    save: bool = True,
    workers: int | None = None,
    progress: bool = True,
    detections: str | os.PathLike | None = None,
    ends_unmixed: bool = False,
    reduce: int | None = None,
    follow_walls: bool = False,
) -> Analysis:
    """Measure the heavy-concentration map of an experiment from its frames.

    Parameters
    ----------
    path : a directory of frames (PNG, JPEG, TIFF or BMP, 8 or 16 bits; name order = time order) holding
        ``experiment.json``, or a TIFF stack (its pages the frames; the file, or a folder holding it
        alone) or a video file with ``experiment.json`` beside it.
    out : map file to write (docs/formats.md ``.npz``); default ``map.npz`` beside
        ``experiment.json``. A folder (existing, or given with a trailing ``/``)
        receives ``NAME.npz`` named after the experiment, so several recordings
        analysed into one folder make a campaign; a missing folder is created.
    smooth : width N [frames] of the centred moving average giving ``c`` from
        ``c_raw`` (odd; 1 = none); recorded as ``smoothing_frames``. Frames
        analysed: with ``every``, N map rows.
    smooth_seconds : the same width as a time [s] instead: N is the odd number of
        map rows nearest to ``smooth_seconds`` times their rate (at least 1).
        Overrides ``smooth``.
    every : analyse every ``every``-th frame of the recording, the first
        included (1: all); the others are not read (a video's are decoded,
        as a stream must be, but not converted). The map's rows are then
        ``every / fps`` apart and its ``fps`` is ``fps / every``: an hour
        filmed at 30 fps holds 108 000 frames, where the segregation
        changes over minutes.
    every_seconds : the same as a time [s]: ``every`` is the whole number of
        frames nearest to ``every_seconds * fps`` (at least 1). Overrides ``every``.
        Stills timed by their own clock (it strays from ``fps``, :func:`frame_times`)
        turn seconds into frames at the clock's mean rate, here and in ``smooth_seconds``.
    preview : directory for annotated preview PNGs of ``preview_count`` frames
        spread over the run (first and last included).
    force : replace existing output files.
    save : write the map (False: only return it).
    workers : threads decoding and analysing frames (default: all cores).
    progress : show a progress bar.
    detections : CSV file to write with one row per sphere counted (see
        :func:`write_detections`).
    ends_unmixed : the run ends un-mixed (a large density ratio): its last
        frame shows the heavy spheres below c0 H and the light above, and its
        spheres are learned from too, labelled by where they sit. Each class
        is then seen high and low, so a look that changes with height (a lamp
        above the cell, the plate's motion blur) is not taken for the
        material. A wrong claim shows in ``class_separation``.
    reduce : analyse the frames reduced this many times (each pixel the mean
        of a reduce x reduce block; 1 = as they are). Default: the largest
        whole factor that leaves the spheres REDUCED_DIAMETER_PX or more
        across (:func:`analysis_reduction`). Centres and radii are returned
        in the frames' own pixels either way.
    follow_walls : count each map row in a window whose lines follow the walls:
        moved as far as the view had moved since the first frames (a knocked
        camera, a cell that shifted) and its lid line as far as the lid had
        risen against the plate (a bed that dilated), as the ``view_steady``
        and ``bed_steady`` checks read them (quality.wall_follow). The checks
        then judge the lines as followed, and the figures ``view_followed_d``
        and ``bed_followed_d`` record the largest moves followed. Off by
        default: each row is counted in the window of experiment.json.

    Every map gets a quality record (:mod:`granseg.measure.quality`), stored
    in the file as ``quality``; a failed check raises a
    :class:`~granseg.measure.quality.QualityWarning` naming it.

    Returns an :class:`Analysis`. A frame that cannot be read or shows no
    spheres becomes a NaN row with a :class:`BadFrameWarning`; bad input
    files or fields raise ValueError / FileNotFoundError naming them.
    """
    for name, flag in (("ends_unmixed", ends_unmixed), ("follow_walls", follow_walls)):
        if not isinstance(flag, bool | np.bool_):
            raise ValueError(f"{name}: expected True or False, got {flag!r}")
    if isinstance(smooth, bool) or not isinstance(smooth, int | np.integer) or smooth < 1 or smooth % 2 == 0:
        raise ValueError(f"smooth: expected an odd number of frames >= 1 (1 = none), got {smooth!r}")
    _check_count("workers", workers, 1, allow_none=True)
    _check_count("preview_count", preview_count, 1)
    _check_count("reduce", reduce, 1, allow_none=True)
    _check_count("every", every, 1, most=MOST_EVERY)
    source, exp_path = open_frames(path)
    exp = load_experiment(exp_path)
    reduce = analysis_reduction(exp.particle_diameter_px) if reduce is None else int(reduce)
    fps = _frame_rate(exp, source)
    given_t0 = exp.t0
    exp, first = from_plate_start(exp, fps, source)
    seen = _reduced_experiment(exp, reduce)
    rate = filming_rate(source, fps) if every_seconds is not None or smooth_seconds is not None else fps
    if every_seconds is not None:
        every = frames_every(every_seconds, rate)
    source.keep(int(every), first)
    filmed = fps  # per frame of the recording
    fps /= int(every)  # the map's rows per second
    _check_times(exp, fps, len(source))
    if smooth_seconds is not None:
        smooth = frames_for_seconds(smooth_seconds, rate / int(every))
    out_path = map_path(out, exp.name, exp_path.parent)
    if save:
        check_creatable(out_path.parent)
        out_path.parent.mkdir(parents=True, exist_ok=True)
        check_writable(out_path, force)
    if detections is not None:
        check_writable(detections, force)
    keep = _preview_indices(len(source), preview_count if preview is not None else 2)
    if ends_unmixed:  # the images of the last frames, one of which labels the classes
        keep |= set(range(max(0, len(source) - END_FRAMES), len(source)))
    if preview is not None:
        check_previews(Path(preview), [source.names[i] for i in sorted(keep) if i < len(source.names)], force)
    spheres, crops, bad, names, spots = _detect_all(source, exp, workers, progress, keep, reduce=reduce,
                                                    keep_walls=follow_walls)
    # from here on in the reduced frames' pixels (``seen``), until _in_frame_pixels
    if follow_walls:  # each frame's spheres told from the walls' hemispheres by its own lines
        apart = wall_follow(_walls_by_row(spheres, seen.window))
        spheres = [_split_at_walls(s, followed_window(seen.window, *f), seen.particle_diameter_px)
                   for s, f in zip(spheres, apart, strict=True)]
    classes = _classify(spheres, seen, crops, spots, ends_unmixed)
    shift = _level_classes(spheres, seen)
    # the rows' lines read again once the classes' shift is off the centres, as the checks read them
    # without following: read before, a move the check flagged (0.054 d) was not followed (0.050)
    follow = wall_follow(_walls_by_row(spheres, seen.window)) if follow_walls else None
    times = frame_times(source, filmed)
    exp, times = plate_start_by_stamps(exp, given_t0, first, source, times)
    seen = replace(seen, t0=exp.t0)
    reduced = _assemble(spheres, seen, times.row_seconds(len(spheres), fps), smooth, names, bad, follow)
    reduced.classes, reduced.first, reduced.every = classes, first, int(every)
    reduced.quality = _assess(reduced, shift, reduce, times, source.bits)
    if times.note is not None:
        log.log(logging.WARNING if times.warn else logging.INFO, "%s: %s", exp.path.parent, times.note)
    result = _in_frame_pixels(reduced, exp, reduce)
    if not result.quality.ok:
        warnings.warn(f"{exp.path.parent}: the map failed its quality checks: "
                      + "; ".join(f"{c.name} {c.value:.3f} (limit {c.rule} {c.limit:.3f})"
                                  for c in result.quality.failed), QualityWarning, stacklevel=2)
    if save:
        result.out = _save(result, out_path, force, fps if times.seconds is None else times.mean_rate())
    if detections is not None:
        result.detections = write_detections(detections, result, force=force)
    if preview is None and not result.quality.ok and save:
        # show the problem without being asked: first and last frame beside the map
        preview = out_path.with_name(out_path.stem + "_preview")
        if preview.exists() and any(preview.iterdir()) and not force:
            log.warning("%s exists; no quality preview written (use --force or --preview DIR)", preview)
            preview = None
    if preview is not None:  # drawn on the reduced frames, as analysed
        result.previews = write_previews(Path(preview), reduced, crops, force)
    return result


# A video's own time stamps count the seconds it was filmed in only where it plays at about the
# rate it was filmed at: a time-lapse (frames filmed seconds apart) or a high-speed camera's video
# (a thousand frames a second) plays tens of times faster or slower, and its stamps count playback.
# Where experiment.json's fps and the stream's own rate differ by more than this factor, the
# stamps are not read as filming times. Not fitted: a phone's variable rate moves its stream's
# average by a few tens of per cent at most (30 slowing to 20 frames/s), a time-lapse or a
# slow-motion recording by ten times or more.
PLAYBACK_FACTOR = 2.0


@dataclass(frozen=True)
class FrameTimes:
    """When the frames were filmed, as far as their own time stamps tell: a video's presentation
    stamps, or the camera clock's time of each still (EXIF, sources.shot_times).

    uneven: how far the stamps stray from an even rate, as a share of the run: a video's from the
    straight line through them (VideoFrames.uneven_times: its rate is the stream's own), a still's
    from the fps given, beyond the clock's resolution (a camera's clock is the filming clock);
    None: frames that tell no times, not checked. seconds: each frame's filming time since the
    first, from the stamps, where they stray by more than quality.FRAME_TIMES_SHARE and can be
    read as filming times (None: frame k is k / fps after the first, exactly or within that
    share); note: why uneven stamps were not read, or that they were; warn: whether the note is a
    warning (stamps not read; a camera's clock that disagrees with the fps given), not a record.
    """

    uneven: float | None = None
    seconds: np.ndarray | None = None
    note: str | None = None
    warn: bool = False

    def mean_rate(self) -> float:
        """Frames per second of filming over the frames read, by their own times (``seconds``)."""
        return (len(self.seconds) - 1) / float(self.seconds[-1] - self.seconds[0])

    def row_seconds(self, n: int, fps: float) -> np.ndarray:
        """Each of ``n`` rows' time since the first [s]: k / fps, or the stamps where they are read
        (rows past the last frame read, a stream cut short, go on at ``fps`` from it)."""
        t = np.arange(n) / fps
        if self.seconds is not None and len(self.seconds) and n:
            k = min(len(self.seconds), n)
            t[:k] = self.seconds[:k]
            t[k:] = self.seconds[k - 1] + np.arange(1, n - k + 1) / fps
        return t


def frame_times(source: FrameDirectory | VideoFrames, fps: float) -> FrameTimes:
    """How the frames just read were filmed in time (FrameTimes); ``fps``: the rate filmed at,
    experiment.json's (or the stream's where it gives none), per frame of the stream."""
    if isinstance(source, FrameDirectory):
        return _shot_times(source, fps)
    uneven = source.uneven_times()
    if uneven is None or uneven <= FRAME_TIMES_SHARE:
        return FrameTimes(uneven)
    stamps = np.asarray(source.times, dtype=float)
    why = (f"frames filmed at an uneven rate (their own time stamps stray from an even one by {uneven:.0%} of "
           f"the run), ")
    if not np.all(np.diff(stamps) > 0):
        return FrameTimes(uneven, None, why + f"but the stamps do not increase: times taken as frames at {fps:g} fps",
                          True)
    plays = source.fps or fps
    if not 1 / PLAYBACK_FACTOR <= plays / fps <= PLAYBACK_FACTOR:
        return FrameTimes(uneven, None, why + f"but the video plays at {plays:g} frames/s against the {fps:g} "
                                              f"filmed (a time-lapse or high-speed recording), so its stamps count "
                                              f"playback: times taken as frames at {fps:g} fps", True)
    return FrameTimes(uneven, stamps - stamps[0], why + "times from the stamps")


def plate_start_by_stamps(exp: Experiment, given_t0: float, first: int, source: FrameDirectory | VideoFrames,
                          times: FrameTimes) -> tuple[Experiment, FrameTimes]:
    """A video cut at the plate's start (a negative ``given_t0``, :func:`from_plate_start`) counts
    the frames before it at ``fps``, for its stamps are read only with the frames kept. Where those
    stamps time the map (``times.seconds``, an uneven rate), the first frame kept was filmed
    ``given_t0`` plus its own stamp after the plate started, not ``first / fps``: a phone that
    filmed a 20 s wait at 20 frames/s, 30 given, puts it 10 s later. ``exp`` with that ``t0``; where the
    stamps put it before the plate started (the ``fps`` given is below the rate filmed), the map
    keeps the frames' count at ``fps`` and ``times`` says why, a warning and a failed
    ``frame_times`` check (a map's times are >= 0)."""
    if not first or times.seconds is None or not isinstance(source, VideoFrames) or not source.times:
        return exp, times
    t0 = given_t0 + float(source.times[0])  # the stream's own time of the first frame kept
    if t0 >= 0:
        log.info("%s: the plate started %.3g s before the first frame kept, by the video's stamps (%.3g s by "
                 "its count of frames at the fps given)", exp.path.parent, t0, exp.t0)
        return replace(exp, t0=t0), times
    note = (f"the video's stamps put its first frame kept {-t0:.3g} s before the plate started (t0 {given_t0:g} s "
            f"counted at the fps given), so the map's times are its frames counted at that fps: are t0 and fps "
            f"right?")
    return exp, replace(times, seconds=None, note=note, warn=True)


def filming_rate(source: FrameDirectory | VideoFrames, fps: float) -> float:
    """Frames filmed per second, for turning seconds into frames (``every_seconds``,
    ``smooth_seconds``): ``fps``, or, for stills whose own clock strays from it and times the map
    (:func:`frame_times`), the clock's mean rate over the folder. A video's stamps are known only
    once it is read: its ``fps``."""
    if isinstance(source, FrameDirectory):
        clock = _shot_times(source, fps)
        if clock.seconds is not None:
            return clock.mean_rate()
    return fps


def _shot_times(source: FrameDirectory, fps: float) -> FrameTimes:
    """frame_times of stills, from their camera's clock (sources.shot_times): where it strays from
    one every 1 / ``fps`` s by more than its resolution and FRAME_TIMES_SHARE of the run (an fps
    given wrong, shots the camera missed), the map's times are the clock's; where the clock
    says the names do not sort in the order shot (a camera's file numbers rolling over from 9999
    to 0001), or gives two stills one time, they cannot be, and frame_times fails."""
    shot = source.clock() if len(source) >= 3 else None
    if shot is None:
        return FrameTimes()
    clock, resolution = shot
    k = np.arange(len(clock)) * source.every  # images of the directory since the first kept
    stray = np.max(np.abs(clock - clock[0] - k / fps)) - resolution  # floored seconds: off by < 1 step
    uneven = max(float(stray), 0.0) / (k[-1] / fps)
    if uneven <= FRAME_TIMES_SHARE:
        return FrameTimes(uneven)
    why = (f"the stills' own clock (EXIF) strays from one every {1 / fps:.4g} s by {uneven:.0%} of the run "
           f"(it shot one every {(clock[-1] - clock[0]) / k[-1]:.4g} s on average), ")
    back = np.flatnonzero(np.diff(clock) < 0)
    if back.size:
        return FrameTimes(uneven, None, why + f"but {source.names[back[0] + 1]} was shot before "
                                              f"{source.names[back[0]]}, though its name sorts after (a camera's "
                                              f"file numbers rolling over?): name the frames in the order shot",
                          True)
    if not np.all(np.diff(clock) > 0):
        return FrameTimes(uneven, None, why + f"but it gives stills one time (a resolution of {resolution:g} s): "
                                              f"check fps", True)
    return FrameTimes(uneven, clock - clock[0], why + "times from the clock (check fps)", True)


@dataclass
class Detected:
    """The spheres of every frame of a recording, without their classes (:func:`detect_frames`).

    spheres: per frame, FrameSpheres (centres in undistorted px) or None for a bad frame;
    names: the frames' names; fps [1/s]; bad_frames: (name, problem) of the frames left out;
    times: when the frames were filmed, as far as their own stamps tell (FrameTimes).
    """

    experiment: Experiment
    fps: float
    spheres: list[FrameSpheres | None]
    names: list[str]
    bad_frames: list[tuple[str, str]]
    times: FrameTimes = field(default_factory=FrameTimes)


def detect_frames(path: str | os.PathLike, *, workers: int | None = None, progress: bool = True) -> Detected:
    """Find the spheres of every frame of ``path`` (frames directory or video with
    ``experiment.json``), as :func:`analyze` does, without telling the two kinds apart:
    what a velocity measurement needs (:mod:`granseg.velocity`)."""
    _check_count("workers", workers, 1, allow_none=True)
    source, exp_path = open_frames(path)
    exp = load_experiment(exp_path)
    fps = _frame_rate(exp, source)
    exp, first = from_plate_start(exp, fps, source)
    source.keep(first=first)
    reduce = analysis_reduction(exp.particle_diameter_px)
    spheres, _, bad, names, _ = _detect_all(source, exp, workers, progress, set(), describe=False, reduce=reduce)
    return Detected(exp, fps, [_sphere_pixels(s, reduce) for s in spheres], names, bad, frame_times(source, fps))


# The detector's lengths in pixels (the rim search's 1.5 px, the smoothing, the
# 3 x 3 peaks of gloss) and its limits were set on spheres 20-64 px across, and
# its time grows with the pixels of a sphere: frames of larger spheres are
# reduced by the largest whole factor that leaves them at least this size.
# BENCHMARKS.md, "Large spheres analysed in reduced frames".
REDUCED_DIAMETER_PX = 40.0
# How far above the plate [diameters] its motion may smear spheres along x, so that their rims
# are also judged by their top and bottom (detect.rim_scores): the smear falls off over the
# shear band, a fifth of the bed or so (three of its fifteen layers).
SMEAR_REACH = 3.0
# the smallest sphere experiment.json accepts (measure.experiment._diameter)
MIN_REDUCED_DIAMETER_PX = 4.0


def analysis_reduction(particle_diameter_px: float) -> int:
    """How many times frames of spheres ``particle_diameter_px`` across are reduced for analysis."""
    return max(1, int(particle_diameter_px // REDUCED_DIAMETER_PX))


def _reduced_experiment(exp: Experiment, reduce: int) -> Experiment:
    """``exp`` as seen in frames reduced ``reduce`` times; ValueError (naming the argument) if the
    spheres would come out smaller than the detector can find."""
    seen = exp.reduced(reduce)
    if seen.particle_diameter_px < MIN_REDUCED_DIAMETER_PX:
        raise ValueError(f"reduce (CLI --reduce): {reduce} would leave the spheres "
                         f"{seen.particle_diameter_px:.1f} px across ({exp.path}: particle_diameter_px "
                         f"{exp.particle_diameter_px:g}); at least {MIN_REDUCED_DIAMETER_PX:g} px are needed")
    return seen


def _in_frame_pixels(result: Analysis, exp: Experiment, reduce: int) -> Analysis:
    """``result`` (analysed in frames reduced ``reduce`` times) with its spheres in the frames' own
    pixels and its experiment as given."""
    return replace(result, experiment=exp, spheres=[_sphere_pixels(s, reduce) for s in result.spheres])


def _sphere_pixels(s: FrameSpheres | None, k: int) -> FrameSpheres | None:
    """One frame's spheres found in the frame reduced k times, in the frame's own pixels: a reduced
    pixel's centre lies at k j + (k - 1) / 2 (Experiment.reduced)."""
    if s is None or k == 1:
        return s
    shift = 0.5 * (k - 1)
    return replace(s, x=k * s.x + shift, y=k * s.y + shift, r=k * s.r, settle=k * s.settle,
                   beside=k * s.beside + shift, reach=(k * s.reach[0], k * s.reach[1]),
                   wall_y=k * s.wall_y + shift, wall_x=k * s.wall_x + shift, at_walls=_sphere_pixels(s.at_walls, k))


def _check_count(name: str, value: Any, least: int, allow_none: bool = False, most: int | None = None) -> None:
    """A whole-number argument (workers, preview_count) that must be >= ``least`` (and <= ``most``
    when given); the CLI's --workers/--preview-count arrive here as well."""
    if value is None and allow_none:
        return
    whole = not isinstance(value, bool) and isinstance(value, int | np.integer)
    if not whole or value < least or (most is not None and value > most):
        cli = "--" + name.replace("_", "-")
        bound = f">= {least}" if most is None else f"from {least} to {most}"
        raise ValueError(f"{name} (CLI {cli}): expected a whole number {bound}, got {short_repr(value)}")


# The longest stride analyze takes [frames]: more than any recording holds (OpenCV counts a
# stream's frames in 32 bits; two years at 30 fps), and within what a float holds exactly.
MOST_EVERY = 2**31 - 1


def frames_for_seconds(seconds: float, fps: float) -> int:
    """The odd number of frames (>= 1) nearest to ``seconds`` of recording at ``fps``: what a
    smoothing window given in time means for a centred moving average."""
    n = _seconds("smooth_seconds", seconds, 0.0) * fps
    return max(1, 2 * int(np.floor(n / 2)) + 1)


def frames_every(seconds: float, fps: float) -> int:
    """The whole number of frames (>= 1) nearest to ``seconds`` of recording at ``fps``: how many
    frames apart the frames analysed lie when the interval is given in time."""
    n = _seconds("every_seconds", seconds) * fps
    if not n <= MOST_EVERY:
        raise ValueError(f"every_seconds (CLI --every-seconds): {seconds!r} s at {fps:g} fps is more than "
                         f"{MOST_EVERY} frames, longer than any recording")
    return max(1, int(np.rint(n)))


def _seconds(name: str, value: Any, least: float | None = None) -> float:
    """A duration argument [s]: finite and > 0 (>= ``least`` when given); ValueError naming it."""
    number = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool | np.bool_)
    if not number or not np.isfinite(value) or (value < least if least is not None else value <= 0):
        cli = "--" + name.replace("_", "-")
        bound = f">= {least:g}" if least is not None else "> 0"
        raise ValueError(f"{name} (CLI {cli}): expected a duration {bound} s, got {value!r}")
    return float(value)


def map_path(out: str | os.PathLike | None, name: str, beside: Path) -> Path:
    """Where the map goes: ``map.npz`` in ``beside`` by default, ``OUT/NAME.npz`` when ``out``
    is a folder (existing, or written with a trailing separator), else ``out`` itself."""
    if out is None:
        return beside / "map.npz"
    text = os.fspath(out)
    p = Path(text)
    if p.is_dir() or text.endswith(("/", os.sep)):
        if not name or name in (".", "..") or "/" in name or os.sep in name:
            raise ValueError(f"experiment name {name!r} cannot name a map file in {p}: give --out a file path")
        return p / f"{name}.npz"
    return p


def _frame_rate(exp: Experiment, source: FrameDirectory | VideoFrames) -> float:
    fps = exp.fps if exp.fps is not None else source.fps
    if not fps or fps <= 0:
        raise ValueError(f"{exp.path}: missing field 'fps' (frames per second)")
    return float(fps)


def from_plate_start(exp: Experiment, fps: float, source: FrameDirectory | VideoFrames) -> tuple[Experiment, int]:
    """The recording from the first frame filmed once the plate moved: ``exp`` with that frame's
    ``t0`` (>= 0) and its index. A negative ``t0`` says the camera was started first; the frames
    before (``-t0 x fps`` of them, the bed at rest) tell nothing of the segregation and are left
    out. ValueError naming ``t0`` where the plate starts after the recording's last frame.

    Stills whose camera clock strays from ``fps`` (the map is then timed by the clock,
    :func:`frame_times`) are cut by the clock too: with fps typed as 0.2 for stills shot every
    2 s, t0 = -4 s leaves out two stills, not one."""
    if exp.t0 >= 0:
        return exp, 0
    if isinstance(source, FrameDirectory) and (clock := _shot_times(source, fps).seconds) is not None:
        if -exp.t0 > clock[-1]:
            raise ValueError(f"{exp.path}: field 't0': {exp.t0:g} s puts the plate's start after the recording's "
                             f"last frame (shot {clock[-1]:g} s after the first, by the stills' own clock)")
        first = int(np.searchsorted(clock, -exp.t0 - 1e-9))  # the first still shot once the plate moved
        return replace(exp, t0=max(0.0, exp.t0 + float(clock[first]))), first
    n = len(source)  # 0 for a video whose header does not tell
    before = -exp.t0 * fps  # frames filmed before the plate moved, as a real number
    if not np.isfinite(before) or (n and before > n - 1):
        raise ValueError(f"{exp.path}: field 't0': {exp.t0:g} s puts the plate's start after the recording's "
                         f"last frame ({n} frames at {fps:g} fps)")
    first = int(np.ceil(before - 1e-9))  # frame `before` itself, if whole, is filmed at t = 0
    return replace(exp, t0=max(0.0, exp.t0 + first / fps)), first


def _check_times(exp: Experiment, fps: float, n: int) -> None:
    """Refuse, before any frame is read, a ``t0`` so large that rows ``1 / fps`` apart get one time
    (t0 = 1e308 s: the map's t would not increase, and only saving it would tell). Doubles lie
    furthest apart at the last row's time: rows 1 / fps apart stay apart if twice that gap is less."""
    last = exp.t0 + max(n - 1, 1) / fps
    if not np.isfinite(last) or 2 * np.spacing(last) >= 1 / fps:
        raise ValueError(f"{exp.path}: fields 't0' and 'fps': frames {1 / fps:.3g} s apart from t0 = {exp.t0:g} s "
                         "do not get distinct times (t0 is the time of the first frame since the plate started)")


def _preview_indices(n: int, count: int) -> set[int]:
    return set(np.unique(np.rint(np.linspace(0, max(n - 1, 0), max(count, 1))).astype(int)).tolist())


# --------------------------------------------------------------------------- pass 1: spheres


class _FrameWorker:
    """Undistort, crop, detect and describe the spheres of one frame.

    ``templates`` are the spheres' appearances, learned once per run (from the
    first readable frame) and only matched afterwards. ``describe``: also
    measure each sphere's appearance (classify.FEATURES) and learn where the
    glossy kind shows the lamps, which only telling the kinds apart needs;
    without it (the velocity tracking) ``features`` are (m, 0).

    ``reduce``: frames are analysed reduced that many times (:func:`analysis_reduction`): every
    frame the worker is given is so reduced (:func:`_seen`), its ``exp`` is the experiment so
    reduced and everything it returns is in reduced pixels. ``image_size`` is the frames' own.
    """

    def __init__(self, exp: Experiment, image_size: tuple[int, int], describe: bool = True, reduce: int = 1,
                 keep_walls: bool = False):
        full, exp = exp, exp.reduced(reduce)
        x0, y0, x1, y1 = exp.window
        m = int(np.ceil(exp.particle_diameter_px))
        self.crop = (*exp.crop_origin(), int(np.ceil(x1)) + m, int(np.ceil(y1)) + m)
        self.bed_rows = (int(np.ceil(y0)) - self.crop[1], int(np.floor(y1)) - self.crop[1])  # in the crop
        self.exp, self.size, self.describe, self.reduce = exp, image_size, describe, reduce
        self.keep_walls = keep_walls  # FrameSpheres.at_walls
        reduced_size = (image_size[0] // reduce, image_size[1] // reduce)
        outside = ValueError(f"{exp.path}: field 'window': {list(full.window)} is outside the image "
                             f"({image_size[0]} x {image_size[1]} px) once undistorted with its "
                             "'camera_matrix' and 'dist_coeffs'")
        if not Undistorter.within_reach(self.crop, reduced_size):  # too large to be seen, or tabled
            raise outside
        self.undistort = Undistorter(exp.camera_matrix, exp.dist_coeffs, reduced_size, self.crop)
        self.templates: Templates | None = None
        self.spots: np.ndarray | None = None  # where glossy spheres show the lamps (classify.learn_spots)
        self.first: tuple[FrameSpheres, np.ndarray] | None = None  # the first frame's spheres and crop
        self.exposure = Exposure(0.0)  # none matched until surveyed
        if not self.undistort.inside_image(exp.window):
            raise outside
        self.reach = self._reach()

    def _reach(self) -> tuple[float, float]:
        """How far [px] beyond the window's left and right sides spheres can be found: to the crop's
        edge, less the strip where detect_particles reports none (INSIDE_RADII); 0 on a side whose
        margin the image does not cover (filled by replicating its border)."""
        x0, y0, x1, y1 = self.exp.window
        edge = 0.5 * INSIDE_RADII * self.exp.particle_diameter_px
        left, right = x0 - self.crop[0] - edge, self.crop[2] - x1 - edge
        return (left if left > 0 and self.undistort.inside_image((self.crop[0], y0, x0, y1)) else 0.0,
                right if right > 0 and self.undistort.inside_image((x1, y0, self.crop[2], y1)) else 0.0)

    def prepare(self, source: FrameDirectory | VideoFrames, first_index: int, first: np.ndarray,
                workers: int = 1) -> None:
        """The run's fixed part: the exposure survey (:meth:`survey`) and the learning from the
        first frame (:meth:`learn`), at once.

        Learning is one thread's work for a second or so and the survey
        mostly decoding, so the two share the cores (the survey with one
        decoding thread fewer). The first frame is the survey's reference:
        matched to it, it stays as it is, so it is learned from unmatched
        while the survey runs, and learned again only if the survey finds
        frames brighter than it, to whose clip it is cut as well.
        """
        with ThreadPoolExecutor(1) as pool:
            surveyed = pool.submit(self.survey, source, first_index, first, max(1, workers - 1))
            self.learn(first)  # under Exposure(0.0): no frame matched yet
            exposure = surveyed.result()
        self.exposure = exposure
        if exposure.clip < 255:
            self.learn(first)
        elif self.first is not None:
            self.first[0].gain_taken_off = exposure.drifting

    def survey(self, source: FrameDirectory | VideoFrames, first_index: int, first: np.ndarray,
               workers: int = 1) -> Exposure:
        """The run's exposure (measure.exposure): the first frame's bed level and the largest gain
        of a few frames spread over the run, which every frame is then matched to."""
        reference = bed_level(self.undistort(_bgr(first)), self.bed_rows)
        # a frame of another size is left out here and reported when it is analysed
        levels = (bed_level(self.undistort(_bgr(img)), self.bed_rows)
                  for _, img in source.some(survey_indices(len(source), first_index), workers, self.reduce, self.size))
        return survey(levels, reference)

    def learn(self, image: np.ndarray) -> None:
        """Learn the spheres' appearances from the first frame (kept None if it shows too few
        spheres), then where on them the glossy kind shows the lamps. The first frame's spheres,
        found on the way, are kept in ``first`` (with their crop) for the run, not found again."""
        d = self.exp.particle_diameter_px
        crop, glare, gain = self._crop(_bgr(image))
        self.templates = learn_templates(crop, d, bands=self._material_bands())
        try:
            first = self._spheres("the first frame", crop, glare, gain, describe=False)  # described below
        except BadFrame:
            return  # reported when the frame is analysed
        if self.describe:  # once the spots are known
            centres = np.column_stack([first.x - self.crop[0], first.y - self.crop[1]])
            self.spots = learn_spots(crop, centres, d, height(first.y, self.exp.window), self.exp.c0, N_LAYERS)
            first.features = sphere_features(crop, centres, d, self.spots)
            if first.at_walls is not None:
                at = first.at_walls
                at.features = sphere_features(crop, np.column_stack([at.x - self.crop[0], at.y - self.crop[1]]), d,
                                              self.spots)
        self.first = (first, crop)

    def _material_bands(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """Rows of the crop (top, bottom) holding only heavy spheres' centres and only light ones' in
        the stratified first frame: above and below the interface at (1 - c0) H, MARGIN layers clear
        of it, and half a diameter clear of the lid and the plate, where no centre can lie."""
        x0, y0, x1, y1 = self.exp.window
        layer = (y1 - y0) / N_LAYERS
        half = 0.5 * self.exp.particle_diameter_px
        interface = y1 - (1.0 - self.exp.c0) * (y1 - y0)
        top = (y0 + half, interface - MARGIN * layer)
        bottom = (interface + MARGIN * layer, y1 - half)
        return tuple((a - self.crop[1], b - self.crop[1]) for a, b in (top, bottom))

    def __call__(self, name: str, image: np.ndarray) -> tuple[FrameSpheres, np.ndarray]:
        """The spheres of frame ``name`` (``image`` reduced ``reduce`` times) and its crop."""
        crop, glare, gain = self._crop(image)
        return self._spheres(name, crop, glare, gain), crop

    def _crop(self, image: np.ndarray) -> tuple[np.ndarray, float, float]:
        """The frame undistorted, cropped, matched to the first frame's exposure and rid of the
        wall's glare; the glare taken off [grey levels] and the exposure gain."""
        undistorted, gain = self.exposure.match(self.undistort(image), self.bed_rows)
        crop, glare = remove_wall_glare(undistorted, self.exp.particle_diameter_px, self.bed_rows)
        return crop, glare, gain

    def _spheres(self, name: str, crop: np.ndarray, glare: float, gain: float,
                 describe: bool | None = None) -> FrameSpheres:
        """The spheres of one prepared frame; their features if ``describe`` (default: the worker's)."""
        d = self.exp.particle_diameter_px
        describe = self.describe if describe is None else describe
        found = detect_particles(crop, d, templates=self.templates, details=True,
                                 smeared_below=self.bed_rows[1] - SMEAR_REACH * d)
        x, y = found[:, 0] + self.crop[0], found[:, 1] + self.crop[1]
        inside = in_window(x, y, self.exp.window)
        # hemispheres fixed to the lid and the plate sit on the wall line,
        # where no free sphere's centre can be
        clear = clear_of_walls(y, self.exp.window, d)
        keep = inside & clear
        if not keep.any():
            raise BadFrame(f"{name}: no spheres detected in the window")
        feats = sphere_features(crop, found[keep, :2], d, self.spots) if describe else np.zeros((keep.sum(), 0))
        x0, y0, x1, y1 = self.exp.window
        beside = ~inside & clear & (y >= y0) & (y < y1)
        walls = inside & ~clear
        at_walls = None
        if self.keep_walls:
            feats_at = (sphere_features(crop, found[walls, :2], d, self.spots) if describe
                        else np.zeros((walls.sum(), feats.shape[1])))
            at_walls = FrameSpheres(x[walls], y[walls], found[walls, 2], found[walls, 3], feats_at, found[walls, 5],
                                    placed=self.templates.placed(found[walls, 4].astype(int)))
        return FrameSpheres(x[keep], y[keep], found[keep, 2], found[keep, 3], feats, found[keep, 5],
                            wall=int(walls.sum()), glare=glare, gain=gain,
                            gain_taken_off=self.exposure.drifting,
                            placed=self.templates.placed(found[keep, 4].astype(int)),
                            beside=np.column_stack([x[beside], y[beside]]), reach=self.reach,
                            wall_y=y[walls], wall_x=x[walls], at_walls=at_walls)


def _seen(source, worker: _FrameWorker, i: int, image: np.ndarray | None) -> np.ndarray:
    """Frame ``i`` as ``worker`` analyses it: reduced ``worker.reduce`` times, after its own size is
    checked against the first frame's. ``image``: the frame decoded (a video's), or None to read
    it from a directory, whose JPEG frames are then decoded at the reduced size (read_image)."""
    if image is None:
        return _bgr(source.read(i, worker.reduce, worker.size))
    check_size(_frame_name(source, i), image.shape[1::-1], worker.size)
    return reduce_frame(_bgr(image), worker.reduce)


def _in_thread(source, worker, i: int, image: np.ndarray | None, keep_crop: bool):
    got = _one_frame(source, worker, i, image)
    if isinstance(got, BadFrame):
        return got
    return got[0], (got[1] if keep_crop else None)


def _detect_all(source, exp, workers, progress, keep, describe=True, reduce=1, keep_walls=False):
    """Every frame's spheres (in the frames reduced ``reduce`` times), the kept frames' crops, the
    bad frames, the names and the learned spots; ``keep_walls``: with FrameSpheres.at_walls."""
    n_workers = max(1, workers or os.cpu_count() or 1)
    first_index, first = _first_image(source)
    _warn_if_grey(first, source, first_index)
    try:
        worker = _FrameWorker(exp, (first.shape[1], first.shape[0]), describe, reduce, keep_walls)
    except ValueError:
        _check_same_size(source, first_index, first)  # a stray first frame, not the window, is to blame
        raise
    # a directory's first frame decoded again as its others will be, at the reduced size
    again = isinstance(source, FrameDirectory) and reduce > 1
    worker.prepare(source, first_index, _seen(source, worker, first_index, None if again else first), n_workers)
    results: dict[int, Any] = {}
    crops: dict[int, np.ndarray] = {}
    n_workers = min(n_workers, len(source))
    # Frames of a directory are decoded inside the worker threads (OpenCV and
    # numpy release the GIL); video frames are decoded here, in stream order.
    pool = ThreadPoolExecutor(n_workers) if n_workers > 1 else None
    # One OpenCV thread per worker: the workers already fill the cores.
    cv_threads = cv2.getNumThreads()
    if pool is not None:
        cv2.setNumThreads(1)
    bar = tqdm(total=len(source), desc="analyze", unit="frame", disable=not progress)
    pending: deque[tuple[int, Future]] = deque()
    try:
        for i, image in source.frames():
            if i == first_index and worker.first is not None:  # found while learning
                _store(i, (worker.first[0], worker.first[1] if i in keep else None), results, crops, bar)
                continue
            if pool is None:
                got = _one_frame(source, worker, i, image)
                _store(i, got if isinstance(got, BadFrame) else (got[0], got[1] if i in keep else None),
                       results, crops, bar)
                continue
            pending.append((i, pool.submit(_in_thread, source, worker, i, image, i in keep)))
            while len(pending) > 3 * n_workers:
                _collect(pending.popleft(), results, crops, bar)
        while pending:
            _collect(pending.popleft(), results, crops, bar)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
            cv2.setNumThreads(cv_threads)
        bar.close()
    names = list(source.names)
    _check_video_length(source, names)
    spheres, bad = [], []
    for i, name in enumerate(names):
        got = results.get(i)
        if isinstance(got, FrameSpheres):
            spheres.append(got)
        else:
            problem = str(got) if got is not None else f"{name}: frame missing from the stream"
            spheres.append(None)
            bad.append((name, problem))
            warnings.warn(f"{problem}; its map row is NaN", BadFrameWarning, stacklevel=3)
    if not any(s is not None for s in spheres):
        raise ValueError(f"{exp.path.parent}: no usable frame ({bad[0][1]})")
    return spheres, crops, bad, names, worker.spots


def _first_image(source) -> tuple[int, np.ndarray]:
    """The first decodable frame and its index (to size the undistortion tables)."""
    if isinstance(source, VideoFrames):
        for i, img in source.frames():
            return i, img
        raise ValueError(f"{source.path}: video holds no readable frame (empty or truncated)")
    problems = []
    for i in range(len(source)):
        try:
            return i, source.read(i)
        except BadFrame as exc:
            problems.append(str(exc))
    raise ValueError(f"{source.directory}: no readable frame ({problems[0]})")


def _check_same_size(source, first_index: int, first: np.ndarray) -> None:
    """Raise naming the first frame when the next readable frame has another size: then the
    window was measured on the others and the first frame is the odd one out."""
    if isinstance(source, VideoFrames):
        return  # a video's frames share one size
    for i in range(first_index + 1, len(source)):
        try:
            other = source.read(i)
        except BadFrame:
            continue
        if other.shape[:2] != first.shape[:2]:
            raise ValueError(f"{source.names[first_index]}: the first frame is {first.shape[1]} x {first.shape[0]} px "
                             f"but {source.names[i]} is {other.shape[1]} x {other.shape[0]} px; every frame of a "
                             "recording must have one size (remove or replace the odd frame)")
        return


def _warn_if_grey(image: np.ndarray, source, index: int) -> None:
    """Say so when the frames carry no colour: the two kinds are then told apart by brightness,
    gloss and texture alone, which fails for two materials of one brightness."""
    grey = image.ndim == 2 or (image.shape[2] >= 3 and np.array_equal(image[..., 0], image[..., 1])
                               and np.array_equal(image[..., 1], image[..., 2]))
    if grey:
        warnings.warn(f"{_frame_name(source, index)}: the frames are greyscale (no colour): heavy and light spheres are told apart "
                      "by brightness, gloss and texture only; check the quality report and the preview",
                      GreyFramesWarning, stacklevel=3)


def _frame_name(source, i: int) -> str:
    """Frame ``i``'s name (a video's frames past the count its header gave have none yet)."""
    return source.names[i] if i < len(source.names) else f"frame {i}"


def _bgr(image: np.ndarray) -> np.ndarray:
    """Colour frames as they come; grey frames (a monochrome camera) as three equal channels."""
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image


def _one_frame(source, worker, i, image):
    name = _frame_name(source, i)
    try:
        return worker(name, _seen(source, worker, i, image))
    except BadFrame as exc:
        return exc


def _collect(item, results, crops, bar) -> None:
    i, fut = item
    _store(i, fut.result(), results, crops, bar)


def _store(i, got, results, crops, bar) -> None:
    if isinstance(got, BadFrame):
        results[i] = got
    else:
        results[i] = got[0]
        if got[1] is not None:
            crops[i] = got[1]
    bar.update(1)


def _check_video_length(source, names: list[str]) -> None:
    """``names``, the frames of ``source`` the map has rows for, where a video's stream ended before
    the frames its header announced: cut short, the frames missing keep their rows (NaN, and the
    bad_frames check counts them); read to its end in time, the header's count was an estimate (a
    variable frame rate in a container that keeps no count) and the map has the frames read."""
    if not (isinstance(source, VideoFrames) and source.decoded is not None and source.decoded < source.expected):
        return
    del names[source.decoded:]
    if source.read_to_its_end():
        log.info("%s: the stream holds %d frames, not the %d its header's length and rate make (a variable "
                 "frame rate); the map has the %d", source.path, source.decoded, source.expected, source.decoded)
        return
    log.warning("%s: stream ends after %d of %d frames (truncated?)", source.path, source.decoded, source.expected)
    names.extend(source.name(i) for i in range(source.decoded, source.expected))


# --------------------------------------------------------------------------- pass 2: classes


def _classify(spheres: list[FrameSpheres | None], exp: Experiment, crops: dict[int, np.ndarray],
              spots: np.ndarray | None, ends_unmixed: bool = False) -> MaterialClasses | None:
    """Give every sphere its class: learned from the first good frame (and the last, if the run ends
    un-mixed: classify.learn_classes), or by explicit colour ranges."""
    good = [s for s in spheres if s is not None]
    if exp.colour_ranges:
        for s in good:
            s.heavy = classify_by_ranges(s.features, exp.colour_ranges)
        return None
    i0 = next(i for i, s in enumerate(spheres) if s is not None)
    try:
        labelled = [(spheres[i0], crops.get(i0))] + ([_last_frame(spheres, crops, i0)] if ends_unmixed else [])
    except ValueError as exc:
        raise ValueError(f"{exp.path.parent}: {exc}") from None
    d = exp.particle_diameter_px
    origin = np.asarray(exp.crop_origin(), dtype=float)
    centres = [np.column_stack([s.x, s.y]) - origin for s, _ in labelled]
    features = np.concatenate([s.features for s, _ in labelled])
    heights = [height(s.y, exp.window) for s, _ in labelled]
    places = np.concatenate([across(s.x, exp.window) for s, _ in labelled])
    # the last frame of a run that ends un-mixed is the first turned upside down
    labelled_by = np.concatenate([heights[0], N_LAYERS - heights[1]]) if ends_unmixed else None
    kept = all(crop is not None for _, crop in labelled)  # the labelled frames' images
    # gloss at the learned spots is tried only where each fold can fit its own spot weights
    rises = ([np.concatenate([disk_rises(crop, c, d) for (_, crop), c in zip(labelled, centres, strict=True)])]
             if kept and spots is not None else None)
    heights = np.concatenate(heights)
    try:
        classes = learn_classes(features, heights, exp.c0, N_LAYERS, rises=rises, labelled_by=labelled_by,
                                across=places)
        if kept:  # the labelled spheres also learned as if smeared by motion
            classes = _smeared_if_blurred(classes, labelled, centres, features, heights, places, labelled_by, good,
                                          exp, spots, rises)
    except ValueError as exc:
        raise ValueError(f"{exp.path.parent}: {exc}") from None
    for s in good:
        s.p_heavy = classes.p_heavy(s.features, height(s.y, exp.window), across(s.x, exp.window))
        s.heavy = s.p_heavy > 0.5
    return classes


# The last frames a run that ends un-mixed may take its labelled spheres from
# (the last one that could be read); their images are kept for it.
END_FRAMES = 3


def _last_frame(spheres: list[FrameSpheres | None], crops: dict[int, np.ndarray],
                i0: int) -> tuple[FrameSpheres, np.ndarray]:
    """The run's last good frame among its last END_FRAMES, and its image."""
    for i in range(len(spheres) - 1, max(i0, len(spheres) - 1 - END_FRAMES), -1):
        if spheres[i] is not None and i in crops:
            return spheres[i], crops[i]
    raise ValueError(f"ends_unmixed (CLI --ends-unmixed): none of the last {END_FRAMES} frames after the first "
                     "could be read, so the run's un-mixed end cannot label the classes")


def _smeared_if_blurred(sharp: MaterialClasses, labelled: list[tuple[FrameSpheres, np.ndarray]],
                        centres: list[np.ndarray], features: np.ndarray, heights: np.ndarray,
                        places: np.ndarray, labelled_by: np.ndarray | None, good: list[FrameSpheres], exp: Experiment,
                        spots: np.ndarray | None, rises: list[np.ndarray] | None) -> MaterialClasses:
    """The classes learned from the labelled frames' spheres (``labelled``: each frame's spheres and
    image; ``centres`` in the image, ``features``, ``heights``, ``places`` (across) and ``labelled_by`` of them all, as
    ``sharp`` was learned) and their smeared copies too, if the run shows motion blur for them to
    undo (classify.blur_test); else ``sharp``, with the test kept."""
    d = exp.particle_diameter_px
    blurred = [smeared_images(crop, d) for _, crop in labelled]  # per frame, one image per smear

    def per_smear(describe) -> list[np.ndarray]:
        return [np.concatenate([describe(images[k], c) for images, c in zip(blurred, centres, strict=True)])
                for k in range(len(blurred[0]))]

    augmented = per_smear(lambda image, c: sphere_features(image, c, d, spots))
    sharp_rises = rises
    if rises is not None:
        rises = rises + per_smear(lambda image, c: disk_rises(image, c, d))
    smeared = learn_classes(features, heights, exp.c0, N_LAYERS, augmented, rises=rises, labelled_by=labelled_by,
                            across=places, light_of=sharp)
    run = np.concatenate([s.features for s in good])
    at = np.concatenate([height(s.y, exp.window) for s in good])
    judged = (sharp, smeared)
    if sharp.field is not None:
        # the test asks whether the smears matter; the light taken off makes the two sets agree more
        # everywhere, which hides where they would disagree, so it is judged with the light left on
        judged = (learn_classes(features, heights, exp.c0, N_LAYERS, rises=sharp_rises, labelled_by=labelled_by),
                  learn_classes(features, heights, exp.c0, N_LAYERS, augmented, rises=rises, labelled_by=labelled_by))
    test = blur_test(at, judged[0].p_heavy(run, at) > 0.5, judged[1].p_heavy(run, at) > 0.5)
    return replace(smeared if test.smeared else sharp, blur=test)


def _level_classes(spheres: list[FrameSpheres | None], exp: Experiment) -> tuple[float, int]:
    """Take the classes' relative shift off (outline.class_shift), half from each: the light
    class's centres moved down by half of it, the heavy class's up. Returns the shift [px] and
    the pairs it was read from."""
    good = [s for s in spheres if s is not None]
    shift, pairs = class_shift([(s.x, s.y, s.heavy) for s in good], exp.particle_diameter_px)
    for s in good:
        s.y = s.y + _half_each(s.heavy, shift)
    return shift, pairs


def _half_each(heavy: np.ndarray, gap_px: float) -> np.ndarray:
    """The move [px, y down] of each sphere that takes a gap of ``gap_px`` between the classes off
    (the light class found that much higher than the heavy), half from each: the light down, the
    heavy up."""
    return np.where(heavy, -0.5, 0.5) * gap_px


def _assess(result: Analysis, shift: tuple[float, int] = (0.0, 0), reduce: int = 1,
            times: FrameTimes | None = None, sample_bits: int | None = None) -> Quality:
    """The quality record of ``result`` (analysed in frames reduced ``reduce`` times; ``times``: when
    the frames were filmed, and whether the map's times come from their own stamps; ``sample_bits``:
    how deep 16-bit frames' samples were read, None for 8-bit ones, stills.run_bits)."""
    good = [s for s in result.spheres if s is not None]
    first = good[0]
    learned = result.classes is not None
    sample = _sampled(good)
    centres = [(np.column_stack([s.x, s.y]), s.beside) for s in sample]  # the sample's, and their neighbours
    d = result.experiment.particle_diameter_px
    return assess(
        n=result.n, n_heavy=result.n_heavy, c0=result.experiment.c0,
        first_heights=height(first.y, result.experiment.window), first_heavy=first.heavy,
        scores=np.concatenate([s.score for s in good]),
        settle=np.concatenate([s.settle for s in good]),
        p_heavy=np.concatenate([s.p_heavy for s in good]) if learned else None,
        separation=result.classes.separation if learned else None,
        n_bad_frames=len(result.bad_frames),
        wall_detections=float(np.mean([s.wall for s in good])),
        wall_glare=float(max(s.glare for s in good)),
        exposure_gain=(float(min(s.gain for s in good)), float(max(s.gain for s in good))),
        exposure_matched=any(s.gain_taken_off for s in good),
        class_shift=shift,
        blur=result.classes.blur if learned else None,
        placed={name: np.concatenate([s.placed[name] for s in good]) for name in good[0].placed},
        gloss_at_spots=result.classes.gloss_at_spots if learned else None,
        vacant=_vacant(sample, result.experiment),
        walls=wall_lines(np.r_[first.y, first.wall_y], result.experiment.window),
        view_lines=_walls_by_row(result.spheres, result.experiment.window, result.follow),
        followed=None if result.follow is None else (_largest(result.follow[:, 0]), _largest(result.follow[:, 1])),
        level=_level(sample, result.experiment.window),
        learned_from_end=learned and result.classes.both_ends,
        light_contrast=result.classes.field.contrast() if learned and result.classes.field is not None else None,
        light_share=result.classes.light_share if learned else None,
        frames_reduced=reduce,
        frames_every=result.every,
        frames_first=result.first,
        frame_times=None if times is None or times.uneven is None else (times.uneven, times.seconds is not None),
        spacing=(sphere_spacing(centres, d), d * reduce),
        across_view=(spacing_across_view(centres, float(np.asarray(result.experiment.camera_matrix)[1, 2])),
                     bool(np.any(result.experiment.dist_coeffs != 0))),
        sample_bits=sample_bits,
    )


def _split_at_walls(s: FrameSpheres | None, window: tuple[float, float, float, float],
                    d: float) -> FrameSpheres | None:
    """``s`` with its spheres and the detections left out at the walls (``s.at_walls``) told apart
    again by ``window``'s lines, as the frame's own were (layers.clear_of_walls): a lid that rose
    leaves the layer under it 0.3 d from the window's own line, where it was taken for the lid's
    hemispheres. The counted spheres come first, in their order; ``s`` as it is without at_walls."""
    if s is None or s.at_walls is None:
        return s
    a = s.at_walls
    y = np.r_[s.y, a.y]
    inside = in_window(np.r_[s.x, a.x], y, window)
    clear = clear_of_walls(y, window, d)
    keep, walls = inside & clear, inside & ~clear

    def pick(which: np.ndarray) -> dict[str, Any]:
        return dict(x=np.r_[s.x, a.x][which], y=y[which], r=np.r_[s.r, a.r][which],
                    score=np.r_[s.score, a.score][which], features=np.concatenate([s.features, a.features])[which],
                    settle=np.r_[s.settle, a.settle][which],
                    placed={k: np.r_[v, a.placed[k]][which] for k, v in s.placed.items()})

    return replace(s, **pick(keep), wall=int(walls.sum()), wall_y=y[walls], wall_x=np.r_[s.x, a.x][walls],
                   at_walls=FrameSpheres(**pick(walls)))


def _walls_by_row(spheres: list, window: tuple[float, float, float, float],
                  follow: np.ndarray | None = None) -> np.ndarray:
    """(n_t, 2) each map row's walls (plate, lid offsets [d], :func:`wall_lines`) against ``window``,
    or against it as each row followed the walls (``follow``, Analysis.follow); NaN for a bad frame.
    Once the classes are known, the layer on the plate is read with their gap there taken off
    (:func:`_plate_class_gap`). The lid is read at its lower percentile, LID_MOVE_QUANTILE, without
    its own hemispheres (:func:`_lid_bumps`)."""
    lines = np.full((len(spheres), 2), np.nan)
    gap = _plate_class_gap(spheres, window)
    bumps_x = _lid_bumps(spheres, window, follow)
    for i, s in enumerate(spheres):
        if s is not None:
            w = row_window(window, follow, i)
            y = s.y
            if s.heavy is not None:  # in the plate's half of the bed only
                low = height(y, w) < N_LAYERS / 2
                y = y + np.where(low, _half_each(s.heavy, gap * (w[3] - w[1]) / N_LAYERS), 0.0)
            across = _near(np.c_[s.wall_x, 0 * s.wall_x], np.c_[bumps_x, 0 * bumps_x],  # across the image only
                           LID_BUMP_REACH * (w[3] - w[1]) / N_LAYERS)
            bump = (height(s.wall_y, w) > N_LAYERS / 2) & across
            read = wall_lines(np.r_[y, s.wall_y[~bump]], w, lid_quantile=LID_MOVE_QUANTILE)
            lines[i] = read.plate, read.lid
    return lines


# The lid's hemispheres are detections left out at the walls, which its reading keeps (a window line
# drawn inside the bed leaves the spheres resting on the lid among them). Read from frame to frame
# at a low percentile (LID_MOVE_QUANTILE), the lid then took the first of its bumps that crossed
# into the reading's band where the frames' content moved down: a view moved down 0.1 d read a bed
# change of 0.066-0.083 as well, and a lid lowered 0.1 d read +0.077, risen (apparatus-S-PP-75-jpeg
# seed 18, bumps-S-PP seed 12). The lid does not turn, so its bumps stay where the first
# LID_BUMP_FRAMES frames found them across the image; a sphere that touches the lid between two
# bumps lies at least 0.87 d across from either (both one diameter across, the bump's centre on the
# lid), so detections at the lid within LID_BUMP_REACH d across of one found there are its bumps
# (BENCHMARKS.md, "The lid's bumps in its reading"). A bump is found in some frames and not in
# others (in 5-24 of 24 frames on the tuning seeds' bumpy scenes); apparatus-S-PP-75-jpeg seed 22's
# middle one first in the fifth frame, so three frames missed it, and its lowered lid read 0.069
# ("The lid's bumps found late"). Only the first frames are looked at, where the view and the lid
# are as the window was drawn: later, a view moved toward the lid pushes the spheres touching it
# into the wall clearance, where they would be taken for bumps.
LID_BUMP_FRAMES = 6
LID_BUMP_REACH = 0.4


def _lid_bumps(spheres: list, window: tuple[float, float, float, float], follow: np.ndarray | None) -> np.ndarray:
    """x [px] of the detections left out at the lid (the lid's half of the window) in the first
    LID_BUMP_FRAMES frames read: where the lid's hemispheres stand across the image."""
    read = [i for i, s in enumerate(spheres) if s is not None][:LID_BUMP_FRAMES]  # only these are looked at
    xs = [spheres[i].wall_x[height(spheres[i].wall_y, row_window(window, follow, i)) > N_LAYERS / 2] for i in read]
    return np.concatenate(xs) if xs else np.zeros(0)


def _plate_class_gap(spheres: list, window: tuple[float, float, float, float]) -> float:
    """How much higher [d] the light class's centres lie than the heavy class's in the layer on the
    plate (quality.WALL_LINE_BAND): the median over the frames holding two of each there, where
    those frames agree on it (the middle half of their gaps within PLATE_GAP_SPREAD), else 0; 0
    before the classes are learned.

    The classes' shift is taken off over the whole bed (_level_classes), but the layer smeared by
    the moving plate keeps a gap of its own: on motion-blur-S-PP seed 7 the steel there read 0.045
    d low and the PP 0.02 d high, so the plate's reading sank 0.06 d as the steel came down into
    that layer while the spheres' true heights stayed put, and a view moved up 0.1 d read 0.047
    (BENCHMARKS.md, "The classes' gap on the plate"). The lid's layer is still, and the same gap
    read there was noise that made its reading drift by 0.05 d as the classes mixed. On a bumpy
    plate each sphere's height is where it nests, and the frames' gaps spread over 0.19-0.34 d (the
    middle half; 0.004-0.026 d on the flat scenes): taken off there, that noise moved
    apparatus-grey-matte-glossy-jpeg seed 7's view by 0.025 d as rendered and read a view moved
    0.1 d as a lid risen."""
    gaps = []
    for s in spheres:
        if s is None or s.heavy is None:
            continue
        h = height(s.y, window)
        near = (h > WALL_LINE_BAND[0]) & (h < WALL_LINE_BAND[1])
        light, heavy = h[near & ~s.heavy], h[near & s.heavy]
        if len(light) >= 2 and len(heavy) >= 2:
            gaps.append(float(np.median(light) - np.median(heavy)))
    if len(gaps) < 3 or np.subtract(*np.percentile(gaps, [75, 25])) > PLATE_GAP_SPREAD:
        return 0.0
    return float(np.median(gaps))


def _largest(moves: np.ndarray) -> float:
    """The move of ``moves`` farthest from 0, with its sign."""
    return float(moves[np.argmax(np.abs(moves))]) if len(moves) else 0.0


def _level(sample: list[FrameSpheres], window: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """How much higher [d] the plate's layer lies at the window's right end than at its left, over the
    frames ``sample``, the reading's error (:func:`quality.level_reading`), and the angle [deg] that
    turns the view by."""
    tilt, error = level_reading([(s.x, s.y) for s in sample], window)
    layer_px = (window[3] - window[1]) / N_LAYERS
    return tilt, error, float(np.degrees(np.arctan2(tilt * layer_px, window[2] - window[0])))


# Frames searched for vacancies and measured for the spheres' spacing, evenly
# spread over the run: a search costs 4-10 ms a frame (190-370 spheres), and
# both checks read a share or a median over the run, which two dozen frames of
# a hundred spheres or more (thousands of spheres) tell well enough to part
# 1 % from 5 %.
SAMPLED_FRAMES = 24


def _sampled(good: list[FrameSpheres]) -> list[FrameSpheres]:
    """Up to SAMPLED_FRAMES of the run's good frames, evenly spread."""
    pick = np.unique(np.linspace(0, len(good) - 1, min(len(good), SAMPLED_FRAMES)).round().astype(int))
    return [good[i] for i in pick]


def _vacant(sample: list[FrameSpheres], exp: Experiment) -> tuple[int, int]:
    """The vacancies (quality.vacancies) of the frames ``sample``, and the spheres found where they
    were looked for."""
    found = [vacancies(s.x, s.y, exp.window, exp.particle_diameter_px, s.beside, s.reach) for s in sample]
    return sum(len(v) for v, _ in found), sum(n for _, n in found)


# --------------------------------------------------------------------------- detections


DETECTION_COLUMNS = ("frame", "x", "y", "r", "class", "p_heavy", "layer")


def write_detections(path: str | os.PathLike, result: Analysis, force: bool = False) -> Path:
    """Write every counted sphere as a CSV row: frame, x, y, r, class, p_heavy, layer.

    frame: the frame's index in the recording (0 = first, in name order;
    analysed with ``every``, the map's row i is frame i x every); x, y: centre
    [undistorted px, y down]; r: radius [px]; class: ``heavy`` or ``light``;
    p_heavy: the learned probability of being heavy (empty with explicit
    colour ranges); layer: 0 at the bottom wall. Written atomically; an
    existing file is kept unless ``force``.
    """
    import csv

    path = Path(path)
    with atomic_path(path, force=force, suffix=".csv") as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(DETECTION_COLUMNS)
        for i, s in enumerate(result.spheres):
            if s is None:
                continue
            layer = layer_index(s.y, result.window_of(i))
            p = s.p_heavy if s.p_heavy is not None else [None] * len(s.x)
            for x, y, r, h, ph, j in zip(s.x, s.y, s.r, s.heavy, p, layer, strict=True):
                w.writerow([result.first + i * result.every, f"{x:.2f}", f"{y:.2f}", f"{r:.2f}", "heavy" if h else "light",
                            "" if ph is None else f"{ph:.4f}", int(j)])
    return path


# --------------------------------------------------------------------------- the map


def _assemble(spheres, exp, seconds, smooth, names, bad, follow=None) -> Analysis:
    """The map of ``spheres`` (per frame, or None), its rows ``seconds`` after the first, each counted
    in the window of ``exp`` or as it followed the walls (``follow``, Analysis.follow)."""
    n_t = len(spheres)
    n = np.zeros((n_t, N_LAYERS), dtype=np.int64)
    nh = np.zeros((n_t, N_LAYERS), dtype=np.int64)
    for i, s in enumerate(spheres):
        if s is not None:
            n[i], nh[i] = layer_counts(s.x, s.y, s.heavy, row_window(exp.window, follow, i))
    missing = np.array([s is None for s in spheres])
    with np.errstate(invalid="ignore", divide="ignore"):
        c_raw = np.where(n > 0, nh / np.maximum(n, 1), np.nan)
    c_raw[missing] = np.nan
    c = moving_average(c_raw, smooth, axis=0)
    c[~np.isfinite(c_raw)] = np.nan
    t = exp.t0 + seconds
    z = (np.arange(N_LAYERS) + 0.5) * D_P
    return Analysis(c, c_raw, n, nh, t, z, smooth, exp, names, spheres, bad, follow=follow)


def _save(result: Analysis, out: Path, force: bool, fps: float) -> Path:
    return save_map(out, c=result.c, t=result.t, z=result.z, **result.experiment.metadata(),
                    n=result.n, n_heavy=result.n_heavy, c_raw=result.c_raw, fps=fps,
                    smoothing_frames=result.smoothing_frames, quality=result.quality.to_json(), force=force)
