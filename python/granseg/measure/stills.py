"""Still images as the analysis reads them: which files are frames, and their samples as 8 bits.

Machine-vision cameras (and the software that saves their frames) write 10-,
12- or 14-bit samples into 16-bit PNG or TIFF files, most often in the low
bits: a 12-bit frame holds 0-4095. OpenCV's plain decoding keeps a 16-bit
sample's high byte, which leaves such a frame 16 grey levels deep (0-15), and
the analysis would go on with it silently. Here a run's depth is read from its
samples instead, one depth for every frame so that the frames keep their
brightness relative to each other, and each frame is shifted down by it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from granseg.errors import BadFrame

__all__ = ["IMAGE_SUFFIXES", "RUN_BITS_FRAMES", "SENSOR_BITS", "decode_still", "run_bits", "run_depth", "sensor_bits",
           "tiff_pages", "to_8bit"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
# What a camera's converter delivers; a file's samples are taken to span the
# smallest of these that holds its largest sample (data written in a 16-bit
# file's high bits, as some cameras do, then spans all 16).
SENSOR_BITS = (8, 10, 12, 14, 16)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Frames a run's depth is read from (run_bits): a frame brighter than all of them
# clips at 255, as a sensor does; decoded only where the files are 16-bit.
RUN_BITS_FRAMES = 5


def sensor_bits(largest: int) -> int:
    """The depth [bits] of samples whose largest is ``largest``: the least of SENSOR_BITS holding it."""
    return next((b for b in SENSOR_BITS if largest < 2 ** b), SENSOR_BITS[-1])


def run_depth(n: int, samples: Callable[[int], np.ndarray | None]) -> int | None:
    """The depth [bits] of a run's 16-bit frames: :func:`sensor_bits` of the largest sample of
    RUN_BITS_FRAMES of its ``n`` frames spread over it, the first and last included;
    ``samples(i)`` gives frame i at its own sample type (None where it is 8-bit, or cannot be read:
    its own reading reports it). None where no frame read is 16-bit."""
    largest = None
    for i in np.unique(np.linspace(0, n - 1, RUN_BITS_FRAMES).round().astype(int)):
        image = samples(int(i))
        if image is not None and image.dtype == np.uint16:
            largest = max(largest or 0, int(image.max()))
    return None if largest is None else sensor_bits(largest)


def run_bits(files: list[Path]) -> int | None:
    """:func:`run_depth` of a folder's still ``files`` (in time order)."""
    def samples(i: int) -> np.ndarray | None:
        try:
            data = files[i].read_bytes()
        except OSError:
            return None
        png = data[:8] == PNG_SIGNATURE
        pages = 0 if png else tiff_pages(data)
        if (png and data[24:25] != b"\x10") or (not png and pages != 1):
            return None  # 8-bit PNG (bit depth in its header), JPEG or BMP, or a stack refused when read
        return _samples(data, tiff=pages == 1)

    return run_depth(len(files), samples)


def to_8bit(image: np.ndarray, bits: int) -> np.ndarray:
    """``image`` as uint8: 16-bit samples of ``bits`` depth shifted down to 8 bits (a sample beyond
    that depth, from a frame brighter than those the depth was read from, is clipped at 255)."""
    if image.dtype == np.uint8:
        return image
    return np.minimum(image >> max(bits - 8, 0), 255).astype(np.uint8)


def decode_still(data: bytes, name: str, gray: bool = False, bits: int | None = None) -> np.ndarray:
    """The image in ``data`` (file ``name``) as BGR uint8 (grey with ``gray``), every depth read:
    16-bit samples shifted down by ``bits`` (their own depth, :func:`sensor_bits`, when None).

    Raises BadFrame when ``data`` is not a readable image, holds floating-point samples, or is a
    TIFF of several pages (a stack is not one frame)."""
    pages = tiff_pages(data)
    if pages > 1:
        raise BadFrame(f"{name}: a TIFF of several pages (a stack): save one image per frame")
    image = _samples(data, gray, tiff=pages == 1)
    if image is None:
        raise BadFrame(f"{name}: not a readable image")
    if image.dtype not in (np.uint8, np.uint16):
        raise BadFrame(f"{name}: {image.dtype} samples; save the frames as 8- or 16-bit integers")
    if image.dtype == np.uint16 and bits is None:
        bits = sensor_bits(int(image.max()))
    return to_8bit(image, bits or 8)


def _samples(data: bytes, gray: bool = False, tiff: bool = False) -> np.ndarray | None:
    """The image in ``data`` (a one-page TIFF where ``tiff``, as the caller has counted its pages) as
    BGR (grey with ``gray``) at the sample type its file holds; None if OpenCV cannot read it."""
    buffer = np.frombuffer(data, np.uint8)
    if tiff:  # TIFF may hold any sample type (OpenCV's conversion asserts on float): read as it is
        return _channels(cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED), gray)
    return cv2.imdecode(buffer, (cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR) | cv2.IMREAD_ANYDEPTH)


def _channels(image: np.ndarray | None, gray: bool) -> np.ndarray | None:
    """A decoded image of 1, 3 or 4 channels (grey, BGR, BGRA) as grey (``gray``) or BGR."""
    if image is None:
        return None
    channels = 1 if image.ndim == 2 else image.shape[2]
    if channels == 1:
        image = image.reshape(image.shape[:2])
    code = {(1, False): cv2.COLOR_GRAY2BGR, (3, True): cv2.COLOR_BGR2GRAY,
            (4, True): cv2.COLOR_BGRA2GRAY, (4, False): cv2.COLOR_BGRA2BGR}.get((channels, gray))
    return image if code is None else cv2.cvtColor(image, code)


def tiff_pages(data: bytes, most: int = 2) -> int:
    """How many pages (image file directories) the TIFF in ``data`` holds, counted up to ``most``;
    0 if ``data`` is not a classic TIFF."""
    order = {b"II": "little", b"MM": "big"}.get(data[:2])
    if order is None or int.from_bytes(data[2:4], order) != 42:
        return 0
    pages, offset, seen = 0, int.from_bytes(data[4:8], order), set()
    while 0 < offset and offset + 2 <= len(data) and pages < most and offset not in seen:  # a loop ends
        pages += 1
        seen.add(offset)
        entries = int.from_bytes(data[offset:offset + 2], order)
        at = offset + 2 + 12 * entries
        offset = int.from_bytes(data[at:at + 4], order) if at + 4 <= len(data) else 0
    return pages
