"""Where frames come from: a directory of images or a video file."""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from granseg._io import cv2_path
from granseg.errors import BadFrame
from granseg.measure.camera import reduce_frame

__all__ = ["BadFrame", "FrameDirectory", "VideoFrames", "open_frames", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class FrameDirectory:
    """Still images (PNG or JPEG) in a directory, in name order; decoded on demand (thread-safe).

    ``first``, ``every``: frame i is the directory's image first + i x every (:meth:`keep`; 0 and 1,
    all of them).
    """

    def __init__(self, directory: Path):
        if not directory.is_dir():
            raise FileNotFoundError(f"{directory}: frames directory not found")
        self.directory = directory
        self.all_files = sorted(p for p in directory.iterdir()
                                if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        self.files = self.all_files
        if not self.files:
            raise ValueError(f"{directory}: no PNG or JPEG frames in the directory")
        self.names = [p.name for p in self.files]
        self.fps: float | None = None
        self.first, self.every = 0, 1

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
        return read_image(self.files[i], reduce, size)

    def frames(self) -> Iterator[tuple[int, np.ndarray | None | BadFrame]]:
        """Frame indices; images are read by the workers (None here)."""
        for i in range(len(self.files)):
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


# JPEG decoded at a half, a quarter or an eighth of its size by libjpeg (its scaled inverse DCT)
_REDUCED_READ = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}


def read_image(path: Path, reduce: int = 1, size: tuple[int, int] | None = None) -> np.ndarray:
    """Decode one PNG/JPEG file strictly: an empty or truncated file is a BadFrame, and so is one
    whose own size (width, height) is not ``size`` (None: any).

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
    img = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    if img is None:
        raise BadFrame(f"{path}: not a readable image")
    check_size(path.name, (img.shape[1], img.shape[0]), size)
    return reduce_frame(img, reduce)


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
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in data[-16:]:
        raise BadFrame(f"{path}: truncated PNG (no IEND chunk)")


# Frames further apart in a stream than this are reached by a seek, not by decoding every frame
# between. The exposure survey (measure.exposure) reads two dozen frames spread over the run:
# grabbed, an hour of H.264 at 1920 x 1440 is a whole extra pass through the stream, where a seek
# decodes from the key frame before its target, up to a camera's key-frame interval (GoPro: 1 s)
# and OpenCV's own step back of 16. So does a stride of more than this (``analyze --every``).
# Nearer frames are grabbed, as a seek then saves nothing (BENCHMARKS.md, "The exposure survey
# seeks in a long video").
SEEK_FRAMES = 300


class VideoFrames:
    """Frames of a video file, decoded in order by OpenCV's VideoCapture.

    ``first``, ``every``: frame i is the stream's frame first + i x every (:meth:`keep`; 0 and 1,
    all of them); the frames before and between are only grabbed or sought, not converted.
    ``expected`` is how many of those frames the header announces, ``decoded`` how many the last
    full read found (None before one).
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
        self.decoded: int | None = None
        self.keep()

    def keep(self, every: int = 1, first: int = 0) -> None:
        """Keep every ``every``-th frame of the stream from frame ``first`` on, that one included."""
        self.first, self.every = first, every
        self.expected = -(-max(self.in_stream - first, 0) // every)
        self.names = [self.name(i) for i in range(self.expected)]

    def name(self, i: int) -> str:
        """Frame ``i``'s name: the file's, then the frame's place in the stream."""
        return f"{self.path.name}#{self.first + i * self.every}"

    def __len__(self) -> int:
        return len(self.names)

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        """Decoded frames in order; stops at the end of the readable stream. Frames kept more than
        SEEK_FRAMES apart (a long stride) are sought (:func:`_move`)."""
        cap = cv2.VideoCapture(cv2_path(self.path))
        i, at = 0, 0  # at: the stream's frame the next grab decodes
        try:
            while _move(cap, at, self.first + i * self.every):
                ok, img = cap.read()
                if not ok:
                    break
                at = self.first + i * self.every + 1
                if i >= len(self.names):
                    self.names.append(self.name(i))
                yield i, img
                i += 1
        finally:
            cap.release()
            self.decoded = i

    def some(self, indices: set[int], workers: int = 1, reduce: int = 1,
             size: tuple[int, int] | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """The frames among ``indices``, in order, reduced ``reduce`` times: what the exposure survey
        needs, frames spread over the run, reached by :func:`_move`. The frames stop where the
        stream does, or cannot be decoded further. ``workers`` and ``size`` are not used (a stream
        is read in order, its frames share one size)."""
        cap = cv2.VideoCapture(cv2_path(self.path))
        at = 0  # the stream's frame the next grab decodes
        try:
            for i in sorted(indices):
                target = self.first + i * self.every
                if not _move(cap, at, target) or not cap.grab():
                    break
                at = target + 1
                ok, img = cap.retrieve()
                if ok:
                    yield i, reduce_frame(img, reduce)
        finally:
            cap.release()


def _move(cap: cv2.VideoCapture, at: int, target: int) -> bool:
    """Bring ``cap``, whose next grab decodes the stream's frame ``at``, to frame ``target``: sought
    if more than SEEK_FRAMES ahead (OpenCV decodes forward from the key frame before it: the frame
    itself in MPEG-4, H.264 and FFV1, tests/test_measure_exposure.py; a stream of another make might
    land a frame off), else by grabbing the frames between (decoded, not converted to BGR). False
    where the stream ends first."""
    if target - at > SEEK_FRAMES and cap.set(cv2.CAP_PROP_POS_FRAMES, target):
        return True
    return _skipped(cap, target - at)


def _skipped(cap: cv2.VideoCapture, n: int) -> bool:
    """Pass over the stream's next ``n`` frames (grabbed, not converted); False where it ends first."""
    return all(cap.grab() for _ in range(n))


def open_frames(path: str | os.PathLike) -> tuple[FrameDirectory | VideoFrames, Path]:
    """The frame source at ``path`` and the experiment.json that describes it."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such frames directory or video file")
    if p.is_dir():
        return FrameDirectory(p), p / "experiment.json"
    return VideoFrames(p), p.parent / "experiment.json"
