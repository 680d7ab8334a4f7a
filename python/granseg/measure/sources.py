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

__all__ = ["BadFrame", "FrameDirectory", "VideoFrames", "open_frames", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class FrameDirectory:
    """Still images (PNG or JPEG) in a directory, in name order; decoded on demand (thread-safe)."""

    def __init__(self, directory: Path):
        if not directory.is_dir():
            raise FileNotFoundError(f"{directory}: frames directory not found")
        self.directory = directory
        self.files = sorted(p for p in directory.iterdir()
                            if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise ValueError(f"{directory}: no PNG or JPEG frames in the directory")
        self.names = [p.name for p in self.files]
        self.fps: float | None = None

    def __len__(self) -> int:
        return len(self.files)

    def read(self, i: int) -> np.ndarray:
        """Frame ``i`` as BGR uint8; BadFrame says what is wrong with its file."""
        return read_image(self.files[i])

    def frames(self) -> Iterator[tuple[int, np.ndarray | None | BadFrame]]:
        """Frame indices; images are read by the workers (None here)."""
        for i in range(len(self.files)):
            yield i, None

    def some(self, indices: set[int], workers: int = 1) -> Iterator[tuple[int, np.ndarray]]:
        """The readable frames among ``indices``, in order (unreadable ones left out).

        Decoded ``workers`` at a time in threads (the exposure survey reads
        24 frames before the analysis starts: 0.4 s of a 30-frame run at
        1920 x 1440), so no more than that many frames are held at once.
        """
        order = sorted(indices)
        threads = max(1, min(int(workers), len(order)))
        with ThreadPoolExecutor(threads) as pool:
            for start in range(0, len(order), threads):
                chunk = order[start:start + threads]
                for i, image in zip(chunk, pool.map(self._readable, chunk), strict=True):
                    if image is not None:
                        yield i, image

    def _readable(self, i: int) -> np.ndarray | None:
        try:
            return self.read(i)
        except BadFrame:
            return None


def read_image(path: Path) -> np.ndarray:
    """Decode one PNG/JPEG file strictly: an empty or truncated file is a BadFrame."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BadFrame(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data:
        raise BadFrame(f"{path}: empty file")
    _check_complete(path, data)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise BadFrame(f"{path}: not a readable image")
    return img


def _check_complete(path: Path, data: bytes) -> None:
    """JPEG must end with its end-of-image marker, PNG with its IEND chunk."""
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise BadFrame(f"{path}: truncated JPEG (no end-of-image marker)")
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in data[-16:]:
        raise BadFrame(f"{path}: truncated PNG (no IEND chunk)")


class VideoFrames:
    """Frames of a video file, decoded in order by OpenCV's VideoCapture."""

    def __init__(self, path: Path):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: video file not found")
        cap = cv2.VideoCapture(cv2_path(path))
        ok = cap.isOpened()
        self.expected = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if ok else 0
        self.fps = float(cap.get(cv2.CAP_PROP_FPS)) if ok else None
        cap.release()
        if not ok:
            raise ValueError(f"{path}: not a video OpenCV can open")
        self.path = path
        self.decoded: int | None = None
        self.names = [f"{path.name}#{i}" for i in range(max(self.expected, 0))]

    def __len__(self) -> int:
        return len(self.names)

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        """Decoded frames in order; stops at the end of the readable stream."""
        cap = cv2.VideoCapture(cv2_path(self.path))
        i = 0
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    break
                if i >= len(self.names):
                    self.names.append(f"{self.path.name}#{i}")
                yield i, img
                i += 1
        finally:
            cap.release()
            self.decoded = i

    def some(self, indices: set[int], workers: int = 1) -> Iterator[tuple[int, np.ndarray]]:
        """The decodable frames among ``indices``, in order: the stream is read through once,
        the frames between only grabbed (not converted to BGR); ``workers`` is not used (a stream
        is read in order)."""
        cap = cv2.VideoCapture(cv2_path(self.path))
        try:
            for i in range(max(indices, default=-1) + 1):
                if not cap.grab():
                    break
                if i in indices:
                    ok, img = cap.retrieve()
                    if ok:
                        yield i, img
        finally:
            cap.release()


def open_frames(path: str | os.PathLike) -> tuple[FrameDirectory | VideoFrames, Path]:
    """The frame source at ``path`` and the experiment.json that describes it."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such frames directory or video file")
    if p.is_dir():
        return FrameDirectory(p), p / "experiment.json"
    return VideoFrames(p), p.parent / "experiment.json"
