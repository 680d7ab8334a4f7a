"""Annotated preview images: what a researcher checks before trusting a map."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from granseg._io import atomic_path, cv2_path
from granseg.measure.classify import AMBIGUOUS
from granseg.measure.layers import N_LAYERS
from granseg.measure.quality import SETTLE_PX, vacancies

__all__ = ["check_previews", "draw_preview", "preview_path", "write_previews"]

HEAVY_BGR = (40, 110, 255)  # orange
LIGHT_BGR = (255, 200, 40)  # sky blue
AMBIGUOUS_BGR = (220, 40, 220)  # magenta: p_heavy between the classes
FAIL_BGR = (20, 20, 200)
PANEL_PX = 230
HEADER_PX = 54  # band above the image for the frame's caption


def preview_path(directory: Path, frame_name: str) -> Path:
    """Where the preview of frame ``frame_name`` goes: ``preview_<frame stem>.png``; a frame of a
    video or a stack (``run.avi#3``) as ``preview_run_3.png`` (the file's stem and the frame's
    place: the stem alone would give every frame of the recording one file)."""
    file, _, place = frame_name.partition("#")
    return directory / f"preview_{Path(file).stem}{'_' + place if place else ''}.png"


def check_previews(directory: Path, frame_names: list[str], force: bool) -> None:
    """Check, before the frames are analysed, that the previews of ``frame_names`` can be written
    into ``directory`` (a folder, or one that can be made) without overwriting any unless ``force``."""
    from granseg._io import check_creatable, check_output_dir

    for name in frame_names:
        cv2_path(preview_path(directory, name))  # OpenCV cannot write a name that is not UTF-8
    if not directory.exists():
        check_creatable(directory)  # made later, with its parents
        return
    check_output_dir(directory, [preview_path(directory, n).name for n in frame_names], force)


def write_previews(directory: Path, result: Any, crops: dict[int, np.ndarray], force: bool) -> list[Path]:
    """Write ``preview_<frame>.png`` for each kept frame into ``directory`` (created if needed)."""
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for i in sorted(crops):
        spheres = result.spheres[i]
        if spheres is None:
            continue
        img = draw_preview(crops[i], result, i)
        path = preview_path(directory, result.frame_names[i])
        cv2_path(path)  # a name OpenCV cannot take is named as the preview's, not its temporary file's
        with atomic_path(path, force=force) as tmp:
            if not cv2.imwrite(cv2_path(tmp), img):
                raise OSError(f"{path}: could not write preview image")
        written.append(path)
    return written


def draw_preview(crop: np.ndarray, result: Any, i: int) -> np.ndarray:
    """The undistorted crop of frame ``i`` with spheres circled by class, layer lines and counts."""
    exp = result.experiment
    ox, oy = exp.crop_origin()
    scale = max(1.0, 700.0 / crop.shape[0])
    img = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    img = (img * 0.85).astype(np.uint8)
    s = result.spheres[i]
    to_px = lambda x, y: (int(round((x - ox + 0.5) * scale - 0.5)), int(round((y - oy + 0.5) * scale - 0.5)))  # noqa: E731
    x0, y0, x1, y1 = result.window_of(i)  # the lines this row was counted in
    for j in range(N_LAYERS + 1):
        yy = y1 - j * (y1 - y0) / N_LAYERS
        cv2.line(img, to_px(x0, yy), to_px(x1, yy), (230, 230, 230), 1, cv2.LINE_AA)
    cv2.rectangle(img, to_px(x0, y0), to_px(x1, y1), (255, 255, 255), 2, cv2.LINE_AA)
    p = s.p_heavy if s.p_heavy is not None else np.where(s.heavy, 1.0, 0.0)
    for x, y, r, h, ph, step in zip(s.x, s.y, s.r, s.heavy, p, s.settle, strict=True):
        colour = AMBIGUOUS_BGR if AMBIGUOUS[0] < ph < AMBIGUOUS[1] else HEAVY_BGR if h else LIGHT_BGR
        cv2.circle(img, to_px(x, y), int(round(r * scale * 0.92)), colour, 2, cv2.LINE_AA)
        if step > SETTLE_PX:  # a centre the outline fit still moves (quality check centres_settled)
            cv2.drawMarker(img, to_px(x, y), FAIL_BGR, cv2.MARKER_TILTED_CROSS, 9, 2, cv2.LINE_AA)
        else:
            cv2.circle(img, to_px(x, y), 2, colour, -1, cv2.LINE_AA)
    holes, _ = vacancies(s.x, s.y, exp.window, exp.particle_diameter_px, s.beside, s.reach)
    radius = int(round(0.5 * exp.particle_diameter_px * scale * 0.92))
    for x, y in holes:  # room for a sphere between those found (quality check vacancies)
        cx, cy = to_px(x, y)
        cv2.circle(img, (cx, cy), radius, FAIL_BGR, 1, cv2.LINE_AA)
        cv2.putText(img, "?", (cx - 5, cy + 6), cv2.FONT_HERSHEY_SIMPLEX, 0.5, FAIL_BGR, 1, cv2.LINE_AA)
    body = np.hstack([img, _panel(img.shape[0], result, i, to_px(0, y0)[1], to_px(0, y1)[1])])
    return np.vstack([_header(body.shape[1], result, i), body])


def _header(width: int, result: Any, i: int) -> np.ndarray:
    """Band above the image: frame name, time, total count, class legend; a failed quality check below."""
    q = getattr(result, "quality", None)
    failed = q is not None and not q.ok
    band = np.full((HEADER_PX + (24 if failed else 0), width, 3), 250, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    dark = (30, 30, 30)
    cv2.putText(band, f"{result.frame_names[i]}   t = {result.t[i]:.1f} s   n = {int(result.n[i].sum())}",
                (8, 20), font, 0.5, dark, 1, cv2.LINE_AA)
    cv2.putText(band, "heavy", (8, 44), font, 0.45, HEAVY_BGR, 2, cv2.LINE_AA)
    cv2.putText(band, "light", (70, 44), font, 0.45, LIGHT_BGR, 2, cv2.LINE_AA)
    cv2.putText(band, "ambiguous", (130, 44), font, 0.45, AMBIGUOUS_BGR, 2, cv2.LINE_AA)
    cv2.drawMarker(band, (236, 40), FAIL_BGR, cv2.MARKER_TILTED_CROSS, 9, 2, cv2.LINE_AA)
    cv2.putText(band, "unsettled", (246, 44), font, 0.45, FAIL_BGR, 1, cv2.LINE_AA)
    cv2.circle(band, (336, 40), 7, FAIL_BGR, 1, cv2.LINE_AA)
    cv2.putText(band, "vacancy", (348, 44), font, 0.45, FAIL_BGR, 1, cv2.LINE_AA)
    cv2.putText(band, f"{result.experiment.heavy} / {result.experiment.light}", (425, 44), font, 0.45, dark,
                1, cv2.LINE_AA)
    if failed:
        text = "QUALITY FAILED: " + ", ".join(c.name for c in q.failed)
        room = max(10, (width - 16) // 8)  # about 8 px a character at this size
        if len(text) > room:
            text = text[:room - 3] + "..."
        cv2.putText(band, text, (8, HEADER_PX + 12), font, 0.45, FAIL_BGR, 1, cv2.LINE_AA)
    return band


def _panel(height: int, result: Any, i: int, top: int, bottom: int) -> np.ndarray:
    """Side panel: per-layer counts n, heavy n_h and c_raw, aligned with the layers."""
    panel = np.full((height, PANEL_PX, 3), 250, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    step = (bottom - top) / N_LAYERS
    for j in range(N_LAYERS):
        y = int(bottom - (j + 0.5) * step + 5)
        n, nh, c = result.n[i, j], result.n_heavy[i, j], result.c_raw[i, j]
        share = "  -  " if not np.isfinite(c) else f"{c:4.2f}"
        cv2.putText(panel, f"L{j:<2d} n={n:<3d} h={nh:<3d} c={share}", (8, y), font, 0.42, (30, 30, 30), 1,
                    cv2.LINE_AA)
    return panel
