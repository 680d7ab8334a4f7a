"""Where frames come from: a directory of images, a TIFF stack or a video file."""

from __future__ import annotations

import itertools
import os
import re
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from granseg._io import cv2_path
from granseg.errors import BadFrame
from granseg.measure.camera import reduce_frame
from granseg.measure.stills import (
    IMAGE_SUFFIXES,
    PNG_SIGNATURE,
    decode_still,
    run_bits,
    run_depth,
    sensor_bits,
    tiff_pages,
    to_8bit,
)

__all__ = ["BadFrame", "FrameDirectory", "TiffStack", "VideoFrames", "open_frames", "IMAGE_SUFFIXES"]


class FrameDirectory:
    """Still images (PNG, JPEG, TIFF or BMP) in a directory, in name order; decoded on demand (thread-safe).

    ``first``, ``every``: frame i is the directory's image first + i x every (:meth:`keep`; 0 and 1,
    all of them).
    """

    def __init__(self, directory: Path):
        if not directory.is_dir():
            raise FileNotFoundError(f"{directory}: frames directory not found")
        self.directory = directory
        # hidden files are not frames: macOS writes "._NAME.png" beside every file it copies to a
        # drive without its own metadata (an exFAT card), which would sort first and shift every row
        self.all_files = _image_files(directory)
        self.files = self.all_files
        if not self.files:
            raise ValueError(f"{directory}: no PNG, JPEG, TIFF or BMP frames in the directory")
        self.names = [p.name for p in self.files]
        _check_one_naming(directory, self.names)
        _check_name_order(directory, self.names)
        _check_not_a_stack(self.files[0])
        self.fps: float | None = None
        self.first, self.every = 0, 1
        self.bits = run_bits(self.files)  # 16-bit frames' depth (stills.run_bits); None: 8-bit

    def keep(self, every: int = 1, first: int = 0) -> None:
        """Keep every ``every``-th image from image ``first`` on, that one included; the others are
        never read."""
        self.files = self.all_files[first::every]
        self.names = [p.name for p in self.files]
        self.first, self.every = first, every

    def __len__(self) -> int:
        return len(self.files)

    def read(self, i: int, reduce: int = 1, size: tuple[int, int] | None = None) -> np.ndarray:
        """Frame ``i`` as BGR uint8, reduced ``reduce`` times (:func:`read_image`); BadFrame says what is
        wrong with its file, also when its own size (width, height) is not ``size``."""
        return read_image(self.files[i], reduce, size, self.bits)

    def clock(self) -> tuple[np.ndarray, float] | None:
        """When each frame kept was shot by its camera's clock, and the clock's resolution
        (:func:`shot_times`); None where the files carry no such time."""
        return shot_times(self.files)

    def frames(self) -> Iterator[tuple[int, np.ndarray | None | BadFrame]]:
        """Frame indices; images are read by the workers (None here)."""
        for i in range(len(self)):
            yield i, None

    def some(self, indices: set[int], workers: int = 1, reduce: int = 1,
             size: tuple[int, int] | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """The readable frames among ``indices``, in order, reduced ``reduce`` times (unreadable ones
        and those whose size is not ``size`` left out).

        Decoded ``workers`` at a time in threads (the exposure survey reads
        24 frames before the analysis starts: 0.4 s of a 30-frame run at
        1920 x 1440), so no more than that many frames are held at once.
        """
        order = sorted(indices)
        threads = max(1, min(int(workers), len(order)))
        with ThreadPoolExecutor(threads) as pool:
            for start in range(0, len(order), threads):
                chunk = order[start:start + threads]
                for i, image in zip(chunk, pool.map(lambda j: self._readable(j, reduce, size), chunk), strict=True):
                    if image is not None:
                        yield i, image

    def _readable(self, i: int, reduce: int, size: tuple[int, int] | None) -> np.ndarray | None:
        try:
            return self.read(i, reduce, size)
        except BadFrame:
            return None


def frame_in_file(path: Path, place: int) -> str:
    """The name of the frame at ``place`` (from 0) of a recording held in one file, a video or a TIFF
    stack: ``run.avi#3`` (previews and detections name it so; ``preview.preview_path`` splits it)."""
    return f"{path.name}#{place}"


def _image_files(directory: Path) -> list[Path]:
    """The images of a frames folder in name order. Hidden files are not frames: macOS writes
    "._NAME.png" beside every file it copies to a drive without its own metadata (an exFAT card),
    which would sort first and shift every row."""
    return sorted(p for p in directory.iterdir()
                  if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))


def _check_not_a_stack(path: Path) -> None:
    """A TIFF of several pages (an ImageJ or camera stack) among other images is a whole recording
    in one file, not a frame: refused before the run starts (its first page alone would be one
    row). A folder holding the stack alone is read as the stack (:func:`open_frames`)."""
    if path.suffix.lower() not in (".tif", ".tiff"):
        return
    try:
        pages = tiff_pages(path.read_bytes(), most=1_000_000)
    except OSError:
        return  # reported when the frame is read
    if pages > 1:
        raise ValueError(f"{path}: a TIFF stack of {pages} pages among other images; granseg reads a folder's "
                         "images as one frame each, and a stack as a whole recording: give the stack's file as "
                         "the recording (experiment.json beside it), or save it as an image sequence "
                         "(ImageJ: File > Save As > Image Sequence)")


def _is_stack(path: Path) -> bool:
    """Whether ``path`` is a TIFF (classic or BigTIFF) whose first series holds more than one image."""
    if path.suffix.lower() not in (".tif", ".tiff"):
        return False
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            return len(tif.series) > 0 and _series_frames(tif.series[0])[0] > 1
    except Exception:  # noqa: BLE001 - not a TIFF tifffile can read: its reading names the problem
        return False


def _series_frames(series) -> tuple[int, str]:
    """How many images (frames) a tifffile series holds, and the axes of one image (YX, YXS, SYX)."""
    axes = series.axes
    image = next(a for a in ("YXS", "SYX", "YX") if axes.endswith(a))
    return int(np.prod(series.shape[:len(axes) - len(image)], dtype=np.int64)), image


class TiffStack(FrameDirectory):
    """The pages of one TIFF file (a stack saved by ImageJ or a high-speed camera's software, an
    OME-TIFF, a BigTIFF) as the frames of a recording, read like a folder's stills: on demand, in
    the worker threads, in page order. Frame i is page first + i x every (:meth:`keep`).

    Read with tifffile, which keeps the file open and its pages found: OpenCV's
    ``imreadmulti(start, count)`` walks the file's chain of pages from its start for every page
    asked, 126 ms for page 1000 of a 3000-page stack and 382 ms for its last, against 0.25 and
    0.46 ms (``benches/bench_tiff_stack.py``, BENCHMARKS.md "A recording as one TIFF stack").
    tifffile also reads ImageJ's stacks larger than 4 GB, which list only their first page (its
    own handling, not tested here). Uncompressed, Deflate and PackBits pages are read
    as they are; LZW and JPEG need the ``imagecodecs`` package, and a stack compressed so without
    it is refused, naming it. 16-bit pages are read at the run's own depth, as stills are
    (:mod:`granseg.measure.stills`). ``fps``: ImageJ's frame interval where the file records it
    (used where experiment.json gives none, as a video's rate is). A stack has no camera clock
    (:meth:`clock`).
    """

    def __init__(self, path: Path):
        import tifffile

        if not path.is_file():
            raise FileNotFoundError(f"{path}: TIFF stack not found")
        self.path = self.directory = path
        try:
            self._tif = tifffile.TiffFile(path)
        except Exception as exc:  # noqa: BLE001 - tifffile raises many kinds for a damaged file
            raise ValueError(f"{path}: not a TIFF file that can be read ({exc})") from None
        self._lock = threading.Lock()  # one file handle, shared by the worker threads
        try:
            self._open(path)
        except ValueError:
            self.close()
            raise
        except Exception as exc:  # noqa: BLE001 - a file tifffile parses but cannot make sense of
            self.close()
            raise ValueError(f"{path}: cannot read the TIFF stack ({type(exc).__name__}: {exc})") from None

    def _open(self, path: Path) -> None:
        series = self._tif.series[0] if self._tif.series else None
        if series is None:
            raise ValueError(f"{path}: a TIFF file with no image")
        n, self._image_axes = _series_frames(series)
        if n < 2:
            raise ValueError(f"{path}: a TIFF of one image, not a recording: give the folder that holds the "
                             "frames, one image each")
        extra = [f"{a} = {k}" for a, k in zip(series.axes[:len(series.axes) - len(self._image_axes)],
                                               series.shape, strict=False) if k > 1]
        if len(extra) > 1:
            raise ValueError(f"{path}: a stack of {', '.join(extra)} ({series.axes}): several images per time "
                             "(channels or planes); save one image per frame, the time series alone")
        if series.dtype not in (np.uint8, np.uint16):
            raise ValueError(f"{path}: {series.dtype} samples; save the stack as 8- or 16-bit integers")
        photometric = int(series.keyframe.photometric)
        if photometric not in (0, 1, 2):  # MINISWHITE, MINISBLACK, RGB
            raise ValueError(f"{path}: pages of photometric interpretation {series.keyframe.photometric.name}; "
                             "save the stack as grey or RGB")
        self._inverted = photometric == 0
        self.all_pages = list(range(n))
        self.pages = self.all_pages
        self.names = [self.name(i) for i in self.pages]
        self.first, self.every = 0, 1
        self.fps = _imagej_rate(self._tif)
        self.bits = None
        try:
            self._samples(0)
        except ValueError as exc:
            if "imagecodecs" not in str(exc):
                raise ValueError(f"{path}: its first page cannot be read ({exc})") from None
            raise ValueError(f"{path}: pages compressed with {series.keyframe.compression.name}, which tifffile "
                             "reads only with the imagecodecs package: pip install imagecodecs, or save the stack "
                             "uncompressed") from None
        self.bits = run_depth(n, self._readable_samples)  # 16-bit pages' depth, as a folder's (None: 8-bit)

    def name(self, page: int) -> str:
        """Page ``page``'s name (:func:`frame_in_file`)."""
        return frame_in_file(self.path, page)

    def keep(self, every: int = 1, first: int = 0) -> None:
        """Keep every ``every``-th page from page ``first`` on, that one included."""
        self.pages = self.all_pages[first::every]
        self.names = [self.name(i) for i in self.pages]
        self.first, self.every = first, every

    def __len__(self) -> int:
        return len(self.pages)

    def clock(self) -> None:
        """A stack's pages carry no camera clock."""
        return None

    def read(self, i: int, reduce: int = 1, size: tuple[int, int] | None = None) -> np.ndarray:
        """Frame ``i`` as BGR uint8, reduced ``reduce`` times; BadFrame says what is wrong with its page,
        also when its size (width, height) is not ``size``."""
        name = self.names[i]
        try:
            image = self._samples(self.pages[i])
        except Exception as exc:  # noqa: BLE001 - a damaged page: tifffile raises many kinds
            raise BadFrame(f"{name}: cannot read the page; is the file damaged or cut short? "
                           f"({type(exc).__name__}: {exc})") from None
        if image.dtype == np.uint16:
            image = to_8bit(image, self.bits or sensor_bits(int(image.max())))
        check_size(name, (image.shape[1], image.shape[0]), size)
        return reduce_frame(image, reduce)

    def _samples(self, page: int) -> np.ndarray:
        """Page ``page`` as grey or BGR at its own sample type."""
        # one file handle, shared by the worker threads; one thread a page, for they fill the cores
        with self._lock:
            image = self._tif.asarray(key=page, series=0, maxworkers=1)
        if self._image_axes == "SYX":  # planar samples
            image = np.moveaxis(image, 0, -1)
        if image.ndim == 3 and image.shape[2] == 1:
            image = image[..., 0]
        if self._inverted:  # 0 is white
            image = np.iinfo(image.dtype).max - image
        if image.ndim == 2:
            return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if image.shape[2] in (3, 4):
            return np.ascontiguousarray(image[..., 2::-1])  # RGB(A) -> BGR
        raise ValueError(f"pages of {image.shape[2]} samples (neither grey nor RGB)")

    def _readable_samples(self, page: int) -> np.ndarray | None:
        """:meth:`_samples`, None where the page cannot be read (a damaged page is reported when read)."""
        try:
            return self._samples(page)
        except Exception:  # noqa: BLE001 - tifffile raises many kinds
            return None

    def close(self) -> None:
        """Close the file (the source is garbage collected otherwise)."""
        tif = getattr(self, "_tif", None)
        if tif is not None:
            tif.close()
            self._tif = None

    def __del__(self) -> None:
        self.close()


def _imagej_rate(tif) -> float | None:
    """Frames per second that ImageJ recorded with a stack (its frame interval, or its fps), else None."""
    meta = tif.imagej_metadata or {}
    for key, rate in (("finterval", lambda v: 1.0 / v), ("fps", lambda v: v)):
        try:
            value = float(meta[key])
        except (KeyError, TypeError, ValueError):
            continue
        if np.isfinite(value) and value > 0:
            return float(rate(value))
    return None


def _naming(name: str) -> str:
    """A frame name with each run of digits as "#": frame_0005.png -> frame_#.png."""
    return re.sub(r"[0-9]+", "#", name)


def _check_one_naming(directory: Path, names: list[str]) -> None:
    """Refuse frames not all named alike: a copy a file manager made (frame_0005 (1).png,
    "frame_0005 copy.png", "frame_0005 - Copy.png") or an image that is not a frame (background.png)
    sorts among the frames and becomes one, and every row after it takes the next row's time. Names
    alike are one text with numbers in the same places (frame_#.png); the fewest-held namings are
    named, with how many frames follow the most-held one. Names that share no naming (shot_a.png,
    shot_b.png) have no numbering to break and are left to their text order."""
    namings: dict[str, list[str]] = {}
    for name in names:
        namings.setdefault(_naming(name), []).append(name)
    common = max(namings, key=lambda k: (len(namings[k]), k))
    if len(namings) < 2 or len(namings[common]) < 2:  # one naming, or names that carry no numbering
        return
    odd = sorted(n for k, held in namings.items() if k != common for n in held)
    shown = ", ".join(odd[:3]) + (f" and {len(odd) - 3} more" if len(odd) > 3 else "")
    raise ValueError(f"{directory}: {shown} {'is' if len(odd) == 1 else 'are'} not named like the other "
                     f"{len(namings[common])} frames ({common}, where # is a number): a copy, or an image that is not "
                     f"a frame? Every image in the folder is taken as a frame in name order, so move "
                     f"{'it' if len(odd) == 1 else 'them'} out (or rename the frames alike)")


def _check_name_order(directory: Path, names: list[str]) -> None:
    """Refuse frames whose names, sorted as text (the frames' time order, DATA.md), put two names
    that differ only in their numbers out of those numbers' order: frame_10.png sorts before
    frame_2.png, so a script that wrote frame_{i}.png without leading zeros would give a map whose
    rows are shuffled in time. Names that differ in their text too are left to their text order."""
    def split(name: str) -> tuple[list[str], list[int]]:
        parts = re.split(r"([0-9]+)", name)
        return parts[0::2], [int(n) for n in parts[1::2]]

    for a, b in itertools.pairwise(names):
        (text_a, numbers_a), (text_b, numbers_b) = split(a), split(b)
        if text_a == text_b and numbers_b < numbers_a:
            raise ValueError(f"{directory}: frame names sort as text, not by their numbers ({a} before {b}), "
                             f"and their text order is taken as time order: number them with leading zeros "
                             f"(frame_0002.png) so that both orders agree")


# JPEG decoded at a half, a quarter or an eighth of its size by libjpeg (its scaled inverse DCT)
_REDUCED_READ = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}


def read_image(path: Path, reduce: int = 1, size: tuple[int, int] | None = None,
               bits: int | None = None) -> np.ndarray:
    """Decode one still strictly: an empty or truncated file is a BadFrame, and so is one whose own
    size (width, height) is not ``size`` (None: any). 16-bit samples are ``bits`` deep
    (:func:`granseg.measure.stills.decode_still`).

    Reduced ``reduce`` times (:func:`granseg.measure.camera.reduce_frame`).
    A JPEG reduced 2, 4 or 8 times is decoded at that size: libjpeg's
    scaled decoding takes half the time of a whole 1920 x 1440 frame
    (18 against 36 ms) and gives each block's mean to 0.3 grey levels
    (mean absolute difference; 99 % within 2 levels, no shift: 0.002 px),
    below the compression's own noise (BENCHMARKS.md, "JPEG decoded at the
    size analysed").
    """
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BadFrame(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data:
        raise BadFrame(f"{path}: empty file")
    _check_complete(path, data)
    buffer = np.frombuffer(data, np.uint8)
    own = jpeg_size(data) if reduce in _REDUCED_READ else None
    if own is not None:
        img = cv2.imdecode(buffer, _REDUCED_READ[reduce])
        w, h = own
        if img is not None and img.shape[:2] == (-(-h // reduce), -(-w // reduce)):  # rounded up
            check_size(path.name, own, size)
            return img[:h // reduce, :w // reduce]  # the whole blocks, as reduce_frame keeps
        # otherwise (turned by its EXIF orientation, say) decoded whole below
    img = decode_still(data, str(path), bits=bits)
    check_size(path.name, (img.shape[1], img.shape[0]), size)
    return reduce_frame(img, reduce)


def shot_times(files: list[Path]) -> tuple[np.ndarray, float] | None:
    """When each still was shot by its camera's clock, in seconds since the first (EXIF
    DateTimeOriginal, with SubSecTimeOriginal where given), and the clock's resolution [s]: 1
    without sub-seconds, the coarsest of the files. None where a file carries no such time (a
    PNG, or a JPEG written by a program rather than a camera) or cannot be opened."""
    from datetime import datetime

    from PIL import Image

    times, resolution, start = [], 0.0, None
    for path in files:
        try:
            with Image.open(path) as im:
                exif = im.getexif().get_ifd(0x8769)  # the Exif IFD
            shot = datetime.strptime(str(exif.get(36867)).strip("\x00 "), "%Y:%m:%d %H:%M:%S")
        except Exception:  # noqa: BLE001 - a malformed header (struct, key, bomb errors alike) tells no time
            return None
        digits = str(exif.get(37521, "")).strip("\x00 ")
        fraction, step = (int(digits) / 10 ** len(digits), 10.0 ** -len(digits)) if digits.isdigit() else (0.0, 1.0)
        start = shot if start is None else start
        times.append((shot - start).total_seconds() + fraction)
        resolution = max(resolution, step)
    return (np.asarray(times, dtype=float), resolution) if times else None


def check_size(name: str, own: tuple[int, int], size: tuple[int, int] | None) -> None:
    """BadFrame naming frame ``name`` when its own size (width, height) is not ``size`` (the first
    frame's; None: any)."""
    if size is not None and tuple(own) != tuple(size):
        raise BadFrame(f"{name}: size {own[0]} x {own[1]} differs from the first frame's {size[0]} x {size[1]}")


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """Width and height from a JPEG's frame header (any SOF marker), None if ``data`` is not a JPEG
    or the header does not say (a height given later, by a DNL marker)."""
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 9 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            i += 2
            continue
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # SOFn, not DHT, JPG, DAC
            h, w = int.from_bytes(data[i + 5:i + 7], "big"), int.from_bytes(data[i + 7:i + 9], "big")
            return (w, h) if w and h else None
        i += 2 + int.from_bytes(data[i + 2:i + 4], "big")
    return None


def _check_complete(path: Path, data: bytes) -> None:
    """JPEG must end with its end-of-image marker, PNG with its IEND chunk."""
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise BadFrame(f"{path}: truncated JPEG (no end-of-image marker)")
    if data[:8] == PNG_SIGNATURE and b"IEND" not in data[-16:]:
        raise BadFrame(f"{path}: truncated PNG (no IEND chunk)")


# How the frames a video is not analysed at are passed over (:class:`_Mover`). A seek
# (CAP_PROP_POS_FRAMES) decodes from the key frame before its target, after OpenCV's own step back
# of 16 frames, so its cost does not grow with the distance but depends on the stream: 26 frames'
# grabbing on the bench's MPEG-4, 22-33 in H.264 with a key frame every 15 (a GoPro's interval is
# 1 s), 162-168 with x264's default of one every 250 (BENCHMARKS.md, "The exposure survey seeks
# in a long video"). OpenCV does not tell the interval, so the stream's own costs decide:
# - frames more than SEEK_FRAMES apart are always sought (a seek does not lose even at an
#   interval of 250; the exposure survey of a long video, a stride of 10 s at 30 fps);
# - frames TRY_SEEK_FRAMES or fewer apart are always grabbed (a seek decodes 16 or more);
# - between, a seek is tried TRIAL_SEEKS times, and then made where the stream's seeks have so far
#   cost less than grabbing the frames between (``analyze --every-seconds 2`` at 30 fps seeks
#   where the key frames lie close, and grabs where they lie far apart).
SEEK_FRAMES = 300
TRY_SEEK_FRAMES = 32
TRIAL_SEEKS = 2


class VideoFrames:
    """Frames of a video file, decoded in order by OpenCV's VideoCapture.

    ``first``, ``every``: frame i is the stream's frame first + i x every (:meth:`keep`; 0 and 1,
    all of them); the frames before and between are only grabbed or sought, not converted.
    ``expected`` is how many of those frames the header announces (exact where ``counted``, the
    container records its frame count: :func:`keeps_frame_count`), ``decoded`` how many the last
    full read found (None before one), ``sought`` how many of them it reached by a seek, ``times``
    the stream's own time [s] of each (its presentation time stamp; :meth:`uneven_times`).
    """

    def __init__(self, path: Path):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: video file not found")
        cap = cv2.VideoCapture(cv2_path(path))
        ok = cap.isOpened()
        self.in_stream = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0) if ok else 0
        self.fps = float(cap.get(cv2.CAP_PROP_FPS)) if ok else None
        cap.release()
        if not ok:
            raise ValueError(f"{path}: not a video OpenCV can open")
        self.path = path
        self.counted = keeps_frame_count(path)
        self.decoded: int | None = None
        self.sought = 0
        self.times: list[float] = []
        self.mover = _Mover()
        self.bits: int | None = None  # OpenCV converts every frame to 8 bits itself (FrameDirectory.bits)
        self.keep()

    def keep(self, every: int = 1, first: int = 0) -> None:
        """Keep every ``every``-th frame of the stream from frame ``first`` on, that one included."""
        self.first, self.every = first, every
        self.expected = -(-max(self.in_stream - first, 0) // every)
        self.names = [self.name(i) for i in range(self.expected)]

    def name(self, i: int) -> str:
        """Frame ``i``'s name (:func:`frame_in_file`)."""
        return frame_in_file(self.path, self.first + i * self.every)

    def __len__(self) -> int:
        return len(self.names)

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        """Decoded frames in order; stops at the end of the readable stream. The frames between those
        kept (a stride) are sought past or grabbed through, whichever is cheaper (:class:`_Mover`);
        each frame's own time is recorded (``times``)."""
        cap = cv2.VideoCapture(cv2_path(self.path))
        i, at = 0, 0  # at: the stream's frame the next grab decodes
        seeks, self.times = self.mover.seeks, []
        try:
            while self.mover.to(cap, at, self.first + i * self.every):
                ok, img = cap.read()
                if not ok:
                    break
                at = self.first + i * self.every + 1
                self.times.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0)
                if i >= len(self.names):
                    self.names.append(self.name(i))
                yield i, img
                i += 1
        finally:
            cap.release()
            self.decoded, self.sought = i, self.mover.seeks - seeks

    def read_to_its_end(self) -> bool:
        """Whether the last full read's frames reach the end of the stream. In a container that
        records its frame count (``counted``), where they are as many as it announces. In one that
        keeps none (Matroska, WebM), OpenCV announces the duration times the nominal rate, more
        frames than a variable-rate stream holds, so such a stream ends early but whole: there,
        where the last frame kept was filmed within ``every`` + 1 frames (at the header's rate) of
        the length announced (a file cut short ends early in time too); False where the stream
        tells no times or no rate."""
        if self.counted:
            return self.decoded is not None and self.decoded >= self.expected
        if not self.times or not self.fps or self.fps <= 0 or not np.isfinite(self.times[-1]):
            return False
        return self.times[-1] >= (self.in_stream - self.every - 1) / self.fps

    def uneven_times(self) -> float | None:
        """How far the last full read's frames were filmed off an even rate, as a share of the run's
        length: the largest distance of a frame's own time (``times``) from the straight line
        fitted to them all against their place in the stream. 0 for a constant frame rate, whatever
        it is (a time-lapse video plays its frames faster than they were filmed, but evenly); one
        frame dropped in an hour 5e-6; a phone's variable rate, slowing in dim light, per cents
        (quality.FRAME_TIMES_SHARE). None where fewer than 3 frames were read or the stream tells
        no times (all alike)."""
        t = np.asarray(self.times, dtype=float)
        k = self.first + self.every * np.arange(len(t), dtype=float)
        if len(t) < 3 or not np.all(np.isfinite(t)) or np.ptp(t) <= 0:
            return None
        slope, offset = np.polyfit(k, t, 1)
        if slope <= 0:
            return None
        return float(np.max(np.abs(t - offset - slope * k)) / (slope * (k[-1] - k[0])))

    def some(self, indices: set[int], workers: int = 1, reduce: int = 1,
             size: tuple[int, int] | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """The frames among ``indices``, in order, reduced ``reduce`` times: what the exposure survey
        needs, frames spread over the run, reached by :class:`_Mover`. The frames stop where the
        stream does, or cannot be decoded further. ``workers`` and ``size`` are not used (a stream
        is read in order, its frames share one size)."""
        cap = cv2.VideoCapture(cv2_path(self.path))
        at = 0  # the stream's frame the next grab decodes
        try:
            for i in sorted(indices):
                target = self.first + i * self.every
                if not self.mover.to(cap, at, target) or not cap.grab():
                    break
                at = target + 1
                ok, img = cap.retrieve()
                if ok:
                    yield i, reduce_frame(img, reduce)
        finally:
            cap.release()


def keeps_frame_count(path: Path) -> bool:
    """Whether the video's container records how many frames it holds, so that OpenCV's count is
    exact: ISO media (MP4, QuickTime, 3GP: a box 'ftyp', 'moov', 'mdat', 'wide', 'free' or 'skip'
    first) and AVI ('RIFF' ... 'AVI '). Matroska, WebM, MPEG-TS and raw streams keep none."""
    with path.open("rb") as f:
        head = f.read(12)
    return head[4:8] in (b"ftyp", b"moov", b"mdat", b"wide", b"free", b"skip") or (
        head[:4] == b"RIFF" and head[8:12] == b"AVI ")


class _Mover:
    """Brings a capture of one stream to the frames asked for, by seeking or by grabbing the frames
    between, whichever the stream's own costs so far say is cheaper (the rules at SEEK_FRAMES).

    ``clock``: seconds (time.perf_counter; the tests give a clock of their own). The costs are
    means over every seek and every frame grabbed through the mover, in every pass through the
    stream (the exposure survey's and the analysis's), so what one pass learned the next uses.
    """

    def __init__(self, clock: Callable[[], float] = time.perf_counter):
        self.clock = clock
        self.seeks, self.seek_seconds = 0, 0.0
        self.grabs, self.grab_seconds = 0, 0.0

    def to(self, cap: cv2.VideoCapture, at: int, target: int) -> bool:
        """Bring ``cap``, whose next grab decodes the stream's frame ``at``, to frame ``target``
        (OpenCV's seek lands on the frame itself in MPEG-4, H.264 and FFV1,
        tests/test_measure_exposure.py; a stream of another make might land a frame off). False
        where the stream ends first."""
        gap = target - at
        if self._seek_pays(gap):
            start = self.clock()
            if cap.set(cv2.CAP_PROP_POS_FRAMES, target):
                self.seeks, self.seek_seconds = self.seeks + 1, self.seek_seconds + self.clock() - start
                return True
        start = self.clock()
        done = _skipped(cap, gap)
        if gap > 0:
            self.grabs, self.grab_seconds = self.grabs + gap, self.grab_seconds + self.clock() - start
        return done

    def _seek_pays(self, gap: int) -> bool:
        if gap > SEEK_FRAMES:
            return True
        if gap <= TRY_SEEK_FRAMES or not self.grabs:  # what a grab costs is learned first
            return False
        if self.seeks < TRIAL_SEEKS:
            return True
        return self.seek_seconds / self.seeks < gap * self.grab_seconds / self.grabs


def _skipped(cap: cv2.VideoCapture, n: int) -> bool:
    """Pass over the stream's next ``n`` frames (grabbed, not converted); False where it ends first."""
    return all(cap.grab() for _ in range(n))


def open_frames(path: str | os.PathLike) -> tuple[FrameDirectory | VideoFrames, Path]:
    """The frame source at ``path`` and the experiment.json that describes it: a folder of stills,
    a TIFF stack (the file, or a folder holding it as its only image) or a video."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such frames directory, TIFF stack or video file")
    if p.is_dir():
        images = _image_files(p)
        if len(images) == 1 and _is_stack(images[0]):
            return TiffStack(images[0]), p / "experiment.json"
        return FrameDirectory(p), p / "experiment.json"
    if p.suffix.lower() in (".tif", ".tiff"):
        return TiffStack(p), p.parent / "experiment.json"
    return VideoFrames(p), p.parent / "experiment.json"
