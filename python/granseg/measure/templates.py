"""Spheres found as matches of their material's mean appearance.

Spheres of one material under fixed lamps look alike. The mean grey patch of
many of them (one template per colour group: the two materials) shows one
sphere against averaged surroundings. Each frame is correlated with every
template over the template's sphere disk only (1.05 radii): the surroundings
are left out because they change as the bed mixes, and a sphere among
neighbours unlike those it was learned among would otherwise be found off
(dark POM among bright glass: up to 5 px), or two such spheres side by side
as one ghost between them (issue 3). Every local maximum of the best
correlation is a candidate; each is then given the template of the group
its colour belongs to, placed at the best match of that template nearby,
and kept if its disk looks like that group's spheres.

A sphere's look changes across the view: lamps beside the camera light the
spheres at the window's left on their left and those at its right on their
right, and spheres seen off the axis show other parts of themselves. A
group's template may therefore change with x (:func:`with_columns`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import cv2
import numpy as np
from scipy.spatial import cKDTree

from granseg.measure.outline import ring_centre

__all__ = ["DiskScores", "Templates", "build_templates", "cut_patches", "find_spheres", "join_templates", "recentred",
           "with_columns"]

TEMPLATE_HALF = 0.75  # template half-size [d]: the sphere, its outline and the gaps around it
DISK = 1.05  # radius of the matched disk [sphere radii]: the sphere and its outline
MIN_SCORE = 0.2  # correlation below which no local maximum is a candidate
KEEP = 0.5  # spheres matching worse than this share of their group's median are dropped
SEARCH_PX = 3  # how far a candidate may move to its own group's best match [px of the match scale]
MATCH_DIAMETER_PX = 32.0  # the disk correlation runs where spheres are at most this wide
# A group's look across the view (with_columns): a quadratic in x, fitted to
# at least COLUMN_MIN_SPHERES of its spheres, matched in COLUMNS columns.
COLUMNS = 8
COLUMN_MIN_SPHERES = 32


@dataclass(frozen=True)
class Templates:
    """Mean appearance of each kind of sphere, learned once and reused for every frame.

    patches: per appearance group, the mean grey patch (float32, side 2 half + 1);
    offsets: (k, 2) position of the sphere centre relative to the patch middle [px];
    radii: (k,) sphere radius [px]; colours: (k, c) mean colour of the group's
    sphere middles (as :func:`_middle_colours` measures it); disks: per group,
    the sphere's disk as a float32 mask over the patch; d: particle diameter [px];
    signs: (k,) per group, +1 if its spheres are brighter than their
    surroundings, -1 if darker (its patch is then of the inverted grey image,
    where its spheres are bright); rim_limits: (k,) per group, the lowest rim
    score of a sphere (see :func:`granseg.measure.detect._examine`), None to
    accept every match; by_match: (k,) per group, True if its spheres are placed
    where its template matches best rather than by a fit to their outline
    (see :func:`granseg.measure.detect.learn_templates`), None for all False;
    ray_bias: (k, N_FIT_RAYS) per group, where the outline fit's edge finder
    puts each ray's edge outside the true outline [px]
    (:func:`granseg.measure.outline.outline_bias`), None for none;
    by_column: per group, None or (edges (COLUMNS - 1,) [px], patches (COLUMNS,
    side, side)): its template in each column of the view, the columns
    split at ``edges`` in x (:func:`with_columns`); None for none;
    nominal_x: (k,) per group, True if its spheres' x comes from a circle of
    the nominal radius (:func:`granseg.measure.detect._nominal_where_side_lit`),
    None for all False; symmetric_y: (k,) per group, True if each of its
    spheres' y is moved to where its own look is most symmetric top to bottom
    (:func:`granseg.measure.detect._y_by_own_symmetry`), None for all False.
    """

    patches: tuple[np.ndarray, ...]
    offsets: np.ndarray
    radii: np.ndarray
    colours: np.ndarray
    disks: tuple[np.ndarray, ...]
    d: float
    signs: np.ndarray
    rim_limits: np.ndarray | None = None
    by_match: np.ndarray | None = None
    ray_bias: np.ndarray | None = None
    by_column: tuple[tuple[np.ndarray, np.ndarray] | None, ...] | None = None
    nominal_x: np.ndarray | None = None
    symmetric_y: np.ndarray | None = None

    def placed(self, groups: np.ndarray) -> dict[str, np.ndarray]:
        """How the spheres of ``groups`` (m,) are placed other than by their outline, per sphere: by
        their template's best match (``by_match``), across the view by a circle of the nominal size
        (``nominal_x``) and up and down where their own look is symmetric (``symmetric_y``). Keyed
        by the names the map's quality record gives their shares."""
        flags = {"placed_by_template_match": self.by_match, "x_by_nominal_circle": self.nominal_x,
                 "y_by_own_symmetry": self.symmetric_y}
        return {name: np.zeros(len(groups), bool) if flag is None else flag[groups] for name, flag in flags.items()}

    @property
    def half(self) -> int:
        return int(np.ceil(TEMPLATE_HALF * self.d))

    @cached_property
    def matched(self) -> MatchScale:
        """The templates as the disk correlation uses them (:class:`MatchScale`), made once per
        set: every frame of a run is matched with them."""
        return MatchScale.of(self)


@dataclass(frozen=True)
class MatchScale:
    """Templates shrunk to where spheres are MATCH_DIAMETER_PX wide (unchanged if they are
    narrower): ``scale`` (shrunk size / true size, the templates' own), ``size`` (the
    shrunk patches' side), per group the ``patches``, the ``disks`` matched and the ``looks``
    per column (None for a group without them, :attr:`Templates.by_column`)."""

    scale: float
    size: int
    patches: tuple[np.ndarray, ...]
    disks: tuple[np.ndarray, ...]
    looks: tuple[tuple[np.ndarray, ...] | None, ...]

    @classmethod
    def of(cls, templates: Templates) -> MatchScale:
        scale = min(1.0, MATCH_DIAMETER_PX / templates.d)
        size = 2 * templates.half + 1
        small = size if scale == 1.0 else max(3, int(round(size * scale)) | 1)
        scale = small / size
        columns = templates.by_column or (None,) * len(templates.patches)
        if small == size:
            return cls(scale, size, templates.patches, templates.disks,
                       tuple(None if part is None else tuple(part[1]) for part in columns))

        def shrunk(t: np.ndarray) -> np.ndarray:
            return cv2.resize(t, (small, small), interpolation=cv2.INTER_AREA)

        return cls(scale, small, tuple(shrunk(t) for t in templates.patches),
                   tuple(_disk(small, off * scale, DISK * r * scale)
                         for off, r in zip(templates.offsets, templates.radii, strict=True)),
                   tuple(None if part is None else tuple(shrunk(look) for look in part[1]) for part in columns))


def join_templates(parts: list[Templates]) -> Templates:
    """One set of templates holding the groups of each of ``parts`` (learned apart, rim limits and ray bias dropped)."""
    by_match = [np.zeros(len(t.patches), dtype=bool) if t.by_match is None else t.by_match for t in parts]
    return Templates(tuple(p for t in parts for p in t.patches), np.concatenate([t.offsets for t in parts]),
                     np.concatenate([t.radii for t in parts]), np.concatenate([t.colours for t in parts]),
                     tuple(m for t in parts for m in t.disks), parts[0].d,
                     np.concatenate([t.signs for t in parts]),
                     by_match=np.concatenate(by_match) if any(b.any() for b in by_match) else None)


def build_templates(smooth: np.ndarray, image: np.ndarray, centres: np.ndarray, d: float,
                    centred: bool = False, sign: int = 1, one_group: bool = False) -> Templates:
    """Mean grey patch of ``smooth`` per colour group of the spheres at ``centres`` (m, 2).

    The groups are the two colour clusters of the spheres' middles in the
    BGR ``image`` (one group with ``one_group``: spheres known to be of one
    material). ``smooth`` shows the spheres bright (inverted when ``sign`` is
    -1). The sphere in each mean patch is located by
    :func:`ring_centre`; with ``centred`` (patches cut around refined
    centres) the offset is zero by definition and only the radius is measured.
    """
    half = int(np.ceil(TEMPLATE_HALF * d))
    size = 2 * half + 1
    patches = cut_patches(smooth, centres, size)
    colours = _middle_colours(image, centres, d)
    groups = np.zeros(len(centres), dtype=int) if one_group else _appearance_groups(colours)
    means, offsets, radii, mean_colours, disks = [], [], [], [], []
    for g in np.unique(groups):
        mean = np.ascontiguousarray(patches[groups == g].mean(axis=0), dtype=np.float32)
        x, y, r = ring_centre(mean, d)
        offset = [0.0, 0.0] if centred else [x - half, y - half]
        means.append(mean)
        offsets.append(offset)
        radii.append(r)
        mean_colours.append(colours[groups == g].mean(axis=0))
        disks.append(_disk(size, offset, DISK * r))
    return Templates(tuple(means), np.array(offsets, dtype=float), np.array(radii, dtype=float),
                     np.array(mean_colours, dtype=float), tuple(disks), float(d), np.full(len(means), int(sign)))


def with_columns(smooth: dict[int, np.ndarray], templates: Templates, spheres: np.ndarray) -> Templates:
    """``templates`` with each group's look across the view, learned from ``spheres`` (m, >= 5: x, y,
    radius, correlation, group) found in the image whose grey versions by sign are ``smooth``.

    Pixel by pixel, the patches cut around a group's spheres are fitted by
    least squares as a quadratic in the spheres' x; the fit is evaluated in
    the middle of each of COLUMNS equal columns of their x range, and each
    column is matched with its own (:meth:`DiskScores.of`). Groups with fewer
    than COLUMN_MIN_SPHERES spheres keep one template. A fit, not a mean per
    column: the spheres near the window's sides are the ones the frame-wide
    template misses (physically based steel over PP under its side panels:
    most PP spheres of the window's outer eighth), so a column's own spheres
    are too few to learn from, while the trend of those found further in
    carries to it (BENCHMARKS.md, "A sphere's look across the view").
    """
    size = 2 * templates.half + 1
    by_column: list[tuple[np.ndarray, np.ndarray] | None] = []
    for g in range(len(templates.patches)):
        mine = spheres[spheres[:, 4] == g]
        if len(mine) < COLUMN_MIN_SPHERES:
            by_column.append(None)
            continue
        image = smooth[int(templates.signs[g])]
        patches = cut_patches(image, mine[:, :2], size)
        lo, hi = float(mine[:, 0].min()), float(mine[:, 0].max())
        mid, half_width = (lo + hi) / 2, max((hi - lo) / 2, 1.0)
        u = (mine[:, 0] - mid) / half_width
        coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(u), u, u * u]), patches.reshape(len(mine), -1),
                                   rcond=None)
        edges = np.linspace(lo, hi, COLUMNS + 1)
        centre = ((edges[:-1] + edges[1:]) / 2 - mid) / half_width
        looks = (np.column_stack([np.ones_like(centre), centre, centre * centre]) @ coef).reshape(COLUMNS, size, size)
        by_column.append((edges[1:-1], looks.astype(np.float32)))
    return replace(templates, by_column=tuple(by_column) if any(c is not None for c in by_column) else None)


def recentred(templates: Templates, group: int, shift: tuple[float, float]) -> Templates:
    """``templates`` with ``group``'s sphere centre moved by ``shift`` (dx, dy) [px]: its patches (the
    frame-wide one and each column's) resampled so that the point ``shift`` from their middle comes
    to the middle, as if they had been cut around centres ``shift`` further on. Offset, disk and
    radius stay: the sphere is where the resampled patch's middle is."""
    move = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])

    def resample(patch: np.ndarray) -> np.ndarray:
        return cv2.warpAffine(patch, move, patch.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE)

    patches = list(templates.patches)
    patches[group] = resample(patches[group])
    by_column = templates.by_column
    if by_column is not None and by_column[group] is not None:
        edges, looks = by_column[group]
        by_column = tuple((edges, np.stack([resample(look) for look in looks])) if g == group else part
                          for g, part in enumerate(by_column))
    return replace(templates, patches=tuple(patches), by_column=by_column)


def cut_patches(image: np.ndarray, centres: np.ndarray, size: int) -> np.ndarray:
    """(m, size, size) patches of ``image`` centred (to sub-pixel) on each of ``centres`` (m, 2)."""
    return np.stack([cv2.getRectSubPix(image, (size, size), (float(x), float(y))) for x, y in centres])


def _disk(size: int, offset, radius: float) -> np.ndarray:
    """Float32 mask of a disk of ``radius`` [px] about the patch middle + ``offset``."""
    half = (size - 1) / 2
    yy, xx = np.mgrid[0:size, 0:size] - half
    return (np.hypot(xx - offset[0], yy - offset[1]) <= radius).astype(np.float32)


def _middle_colours(image: np.ndarray, centres: np.ndarray, d: float) -> np.ndarray:
    """Mean colour (m, c) of the middle of each sphere: a box of half a diameter around the centre."""
    img = image if image.ndim == 3 else image[..., None]
    h, w = img.shape[:2]
    xi = np.clip(np.rint(centres[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.rint(centres[:, 1]).astype(int), 0, h - 1)
    k = max(1, int(0.25 * d))
    # box sums at the centres only, from the integral of the image padded as
    # cv2.blur pads it (reflect 101): blurring the whole frame to read ~150
    # points of it took 6 ms a frame at D = 80 px
    padded = cv2.copyMakeBorder(img, k, k, k, k, cv2.BORDER_REFLECT_101).reshape(h + 2 * k, w + 2 * k, -1)
    depth = cv2.CV_32S if padded.dtype == np.uint8 and padded.size < 2 ** 23 else cv2.CV_64F  # exact sums
    total = cv2.integral(padded, sdepth=depth).reshape(h + 2 * k + 1, w + 2 * k + 1, -1)
    x1, y1 = xi + 2 * k + 1, yi + 2 * k + 1
    corner = [total[r, c].astype(np.float64) for r, c in ((y1, x1), (yi, x1), (y1, xi), (yi, xi))]
    box = corner[0] - corner[1] - corner[2] + corner[3]
    return (box / (2 * k + 1) ** 2).astype(np.float32)


def _appearance_groups(colour: np.ndarray) -> np.ndarray:
    """Split spheres into two groups by the colour of their middles (2-means); one group if alike.

    Deterministic: the best split along the colours' principal axis (exact,
    over every cut of the sorted projections) starts Lloyd's iterations.
    cv2.kmeans seeds from OpenCV's global random state, so the same frame
    split differently depending on what ran before; where the colours form
    one cloud (black beads only) the split, and with it the templates and
    centres (by up to 0.02 px), changed from run to run.
    """
    colour = np.asarray(colour, dtype=float)
    if len(colour) < 4 or np.ptp(colour, axis=0).max() < 1e-3:
        return np.zeros(len(colour), dtype=int)
    centred = colour - colour.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    proj = centred @ axis
    order = np.argsort(proj, kind="stable")
    p = proj[order]
    n = np.arange(1, len(p))  # size of the lower part for each cut
    s1, s2 = np.cumsum(p)[:-1], np.cumsum(p * p)[:-1]
    total, total2 = p.sum(), (p * p).sum()
    within = (s2 - s1 * s1 / n) + ((total2 - s2) - (total - s1) ** 2 / (len(p) - n))
    labels = np.zeros(len(p), dtype=int)
    labels[order[int(np.argmin(within)) + 1:]] = 1
    for _ in range(30):
        if min(np.bincount(labels, minlength=2)) == 0:
            break
        centres = np.stack([colour[labels == g].mean(axis=0) for g in (0, 1)])
        new = np.argmin(((colour[:, None, :] - centres[None]) ** 2).sum(axis=2), axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    if min(np.bincount(labels, minlength=2)) < 3:
        return np.zeros(len(colour), dtype=int)
    return labels


# --------------------------------------------------------------------------- matching


@dataclass(frozen=True)
class DiskScores:
    """Per group, the correlation of its template's disk with the image at every position.

    Computed where a sphere is at most MATCH_DIAMETER_PX across (the image
    and the templates shrunk by ``scale``): the match only has to start the
    outline fit, which works at full resolution, within a fraction of a
    pixel, and on 80 px spheres the full-size correlation took 86 ms a frame.
    maps: (k, H', W'); maps[g, i, j] is the score with the shrunk template's
    top-left at padded pixel (j, i) of the shrunk image.
    """

    maps: np.ndarray
    pad: int
    half: int
    scale: float  # shrunk size / true size (the templates' own, within a pixel of the image's)

    @classmethod
    def of(cls, smooth: dict[int, np.ndarray], templates: Templates) -> DiskScores:
        """``smooth``: the grey image by sign (+1 as is, -1 inverted); each group is matched on its own sign's."""
        match = templates.matched
        scale, small_size = match.scale, match.size
        half = (small_size - 1) // 2
        pad = half + SEARCH_PX + 2
        padded = {}
        for sign in np.unique(templates.signs).tolist():
            image = smooth[sign]
            if scale != 1.0:
                image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            padded[sign] = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
            padded[sign] -= padded[sign].mean()  # keeps the float32 sums of squares precise
        columns = templates.by_column or (None,) * len(match.patches)
        geometry = cls(np.zeros((0, 1, 1), np.float32), pad, half, scale)  # map <-> image coordinates
        maps = []
        # groups of one sign and one disk share the image's spread under it:
        # two of a frame's largest correlations (5 ms at 80 px, BENCHMARKS.md)
        spreads: dict[tuple[int, tuple[int, ...], bytes], np.ndarray] = {}
        for g, (t, m, s, part, looks) in enumerate(zip(match.patches, match.disks, templates.signs, columns,
                                                        match.looks, strict=True)):
            image = padded[int(s)]
            key = (int(s), m.shape, m.tobytes())
            if key not in spreads:
                spreads[key] = _masked_spread(image, m)
            spread = spreads[key]
            if part is None:
                maps.append(_masked_correlation(image, t, m, spread))
                continue
            # each column of the map correlated with its own column's template,
            # on the strip of the image that column's matches cover
            edges = part[0]
            cols = np.arange(spread.shape[1], dtype=float)
            x, _ = geometry.to_image(cols, cols, np.repeat(templates.offsets[g:g + 1], len(cols), axis=0))
            column = np.searchsorted(edges, x)
            out = np.empty_like(spread)
            for c in np.unique(column):
                first, last = np.flatnonzero(column == c)[[0, -1]]
                out[:, first:last + 1] = _masked_correlation(image[:, first:last + small_size], looks[c], m,
                                                             spread[:, first:last + 1])
            maps.append(out)
        return replace(geometry, maps=np.stack(maps))

    def to_image(self, col: np.ndarray, row: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sphere centre (x, y) [px] for a (sub-pixel) map position and its group's offset (m, 2) [px]."""
        shift = self.half - self.pad
        x = (col + shift + 0.5) / self.scale - 0.5 + offset[:, 0]
        y = (row + shift + 0.5) / self.scale - 0.5 + offset[:, 1]
        return x, y

    def to_map(self, x: np.ndarray, y: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest whole map position (col, row) for sphere centres (x, y) [px]."""
        shift = self.half - self.pad
        col = (x - offset[:, 0] + 0.5) * self.scale - 0.5 - shift
        row = (y - offset[:, 1] + 0.5) * self.scale - 0.5 - shift
        return np.rint(col).astype(int), np.rint(row).astype(int)


def find_spheres(smooth: dict[int, np.ndarray], image: np.ndarray, templates: Templates) -> np.ndarray:
    """Spheres in one frame: (m, 5) x, y, radius [px], disk correlation, group.

    ``smooth`` is the lightly blurred grey image by sign (+1 as is, -1
    inverted; those of the templates' signs), ``image`` the BGR one (for the
    colours that decide the groups).
    """
    scores = DiskScores.of(smooth, templates)
    # Groups of opposite polarity are searched apart: a gap between bright
    # spheres is a dark blob and matches a dark sphere's template as well as
    # the spheres match theirs, and found together its peak would hide the
    # three spheres around it (the detector settles such overlaps once every
    # candidate's outline is known, detect._one_per_place).
    found = np.concatenate([_peaks(scores, templates, templates.signs == s) for s in np.unique(templates.signs)])
    found = _colour_groups(found, image, templates)
    found = _locate(scores, found, templates)
    return _keep(found)


def _peaks(scores: DiskScores, templates: Templates, groups: np.ndarray) -> np.ndarray:
    """Local maxima of the best of ``groups``' (mask over the groups) scores, at most one within 0.7
    diameter: (m, 5)."""
    d = templates.d
    index = np.flatnonzero(groups)
    if len(index) == 1:  # a view, not a copy
        maps = scores.maps[index[0]:index[0] + 1]
    elif len(index) < len(scores.maps):
        maps = scores.maps[index]
    else:  # one polarity: every group
        maps = scores.maps
    score = maps[0] if len(maps) == 1 else maps.max(axis=0)
    best = index[_first_at(maps, score)]
    size = max(3, int(0.6 * d * scores.scale) | 1)
    peak = (score >= cv2.dilate(score, np.ones((size, size), np.uint8))) & (score > MIN_SCORE)
    peak[[0, -1], :] = peak[:, [0, -1]] = False
    rows, cols = np.nonzero(peak)
    group = best[rows, cols]
    x, y = scores.to_image(cols.astype(float), rows.astype(float), templates.offsets[group])
    found = np.column_stack([x, y, templates.radii[group], score[rows, cols], group])
    return found[keep_apart(found[:, :2], np.argsort(-found[:, 3]), 0.7 * d)]


def keep_apart(points: np.ndarray, order: np.ndarray, distance: float) -> list[int]:
    """The indices of ``points`` (m, 2) kept when they are visited in ``order`` and each is kept
    unless a point kept before lies closer than ``distance``; in the order they were kept.
    ``order`` may leave points out.

    The same as comparing each point with every kept one (np.hypot), from
    the close pairs a KD-tree offers, each checked with np.hypot: 0.4 ms
    instead of 6.4 for 300 candidates. A point that is not finite
    is kept and keeps none away.
    """
    order = np.asarray(order, dtype=np.intp)
    points = np.asarray(points, dtype=float)
    finite = np.flatnonzero(np.isfinite(points).all(axis=1))
    # a little wider than ``distance``: the tree's distances may round otherwise than np.hypot
    near = cKDTree(points[finite].reshape(-1, 2)).query_pairs(distance * (1 + 1e-9) + 1e-9, output_type="ndarray")
    i, j = finite[near.reshape(-1, 2)].T
    close = np.hypot(*(points[i] - points[j]).T) < distance
    one, other = np.concatenate([i[close], j[close]]), np.concatenate([j[close], i[close]])
    by_one = np.argsort(one, kind="stable")
    one, other = one[by_one], other[by_one]
    starts = np.searchsorted(one, np.arange(len(points) + 1))
    blocked = np.zeros(len(points), dtype=bool)
    kept: list[int] = []
    for k in order.tolist():
        if not blocked[k]:
            kept.append(k)
            blocked[other[starts[k]:starts[k + 1]]] = True
    return kept


def _first_at(maps: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Per pixel, the first of ``maps`` (g, h, w) equal to ``score`` (their maximum): ``np.argmax``
    over the groups wherever no map is NaN. argmax along the first axis walks the maps in
    strides: 10.5 ms for two 520 x 720 maps, against 7.0 ms here with the maximum."""
    first = np.full(score.shape, len(maps) - 1, dtype=np.intp)
    for g in range(len(maps) - 2, -1, -1):
        first[maps[g] == score] = g
    return first


def _colour_groups(found: np.ndarray, image: np.ndarray, templates: Templates) -> np.ndarray:
    """Each candidate's group is the one nearest in colour (its radius and offset follow).

    The correlation alone does not tell the groups apart when the two
    materials share a shape and highlights (dark POM and green glass under
    the same lamps: a POM sphere matched the glass template better and took
    its radius, issue 3); the groups were made by colour, so colour decides.
    """
    if len(templates.patches) < 2 or len(found) == 0:
        return found
    colour = _middle_colours(image, found[:, :2], templates.d)
    distance = ((colour[:, None, :] - templates.colours[None]) ** 2).sum(axis=2)
    # never to a group of the other polarity: the polarity was found by the
    # search (find_spheres), and transparent glass takes the colour of what
    # lies behind it (glass among glass went to the POM group by colour)
    sign = templates.signs[found[:, 4].astype(int)]
    distance[sign[:, None] != templates.signs[None, :]] = np.inf
    group = np.argmin(distance, axis=1)
    out = found.copy()
    out[:, :2] += templates.offsets[group] - templates.offsets[found[:, 4].astype(int)]
    out[:, 2] = templates.radii[group]
    out[:, 4] = group
    return out


def _locate(scores: DiskScores, found: np.ndarray, templates: Templates) -> np.ndarray:
    """Move each sphere to its own group's best match within SEARCH_PX, to sub-pixel."""
    out = found.copy()
    offs = np.arange(-SEARCH_PX, SEARCH_PX + 1)
    for g in np.unique(found[:, 4]).astype(int):
        mine = np.flatnonzero(found[:, 4] == g)
        score = scores.maps[g]
        offset = templates.offsets[np.full(len(mine), g)]
        col, row = scores.to_map(found[mine, 0], found[mine, 1], offset)
        cols = np.clip(col[:, None, None] + offs[None, None, :], 1, score.shape[1] - 2)
        rows = np.clip(row[:, None, None] + offs[None, :, None], 1, score.shape[0] - 2)
        cols, rows = (a.reshape(len(mine), -1) for a in np.broadcast_arrays(cols, rows))
        best = np.argmax(score[rows, cols], axis=1)
        bc, br = cols[np.arange(len(mine)), best], rows[np.arange(len(mine)), best]
        fx = _parabola(score[br, bc - 1], score[br, bc], score[br, bc + 1])
        fy = _parabola(score[br - 1, bc], score[br, bc], score[br + 1, bc])
        out[mine, 0], out[mine, 1] = scores.to_image(bc + fx, br + fy, offset)
        out[mine, 3] = score[br, bc]
    return out


def _keep(found: np.ndarray) -> np.ndarray:
    """Drop candidates whose disk matches their group's template far worse than its spheres do.

    "Far worse" is below KEEP of the group's median. Every real sphere of the
    synthetic looks scores at least 0.67 of its group's median (medians
    0.95-1.0); a void in the packing, where the dark background shows, scores
    below zero (issue 3).
    """
    keep = np.zeros(len(found), dtype=bool)
    for g in np.unique(found[:, 4]):
        mine = found[:, 4] == g
        keep |= mine & (found[:, 3] > KEEP * np.median(found[mine, 3]))
    return found[keep]


def _masked_correlation(image: np.ndarray, template: np.ndarray, mask: np.ndarray,
                        spread: np.ndarray | None = None) -> np.ndarray:
    """Normalised cross-correlation of ``template`` with ``image`` over the pixels where ``mask`` is 1.

    As ``cv2.matchTemplate(..., TM_CCOEFF_NORMED, mask=mask)``, but from three
    plain correlations (a third of the time): the template made zero-mean
    on the mask, and the mask's sums of the image and of its square (its
    ``spread``, :func:`_masked_spread`, which may be given: it does not
    depend on the template).
    """
    n = float(mask.sum())
    tz = mask * (template - float((mask * template).sum()) / n)
    num = cv2.matchTemplate(image, tz.astype(np.float32), cv2.TM_CCORR)
    spread = _masked_spread(image, mask) if spread is None else spread
    return num / (np.sqrt(float((tz * tz).sum())) * spread)


def _masked_spread(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The square root of n times the variance of ``image`` under ``mask`` (n pixels) at every placement."""
    n = float(mask.sum())
    s1 = cv2.matchTemplate(image, mask, cv2.TM_CCORR)
    s2 = cv2.matchTemplate(image * image, mask, cv2.TM_CCORR)
    return np.sqrt(np.maximum(s2 - s1 * s1 / n, 1e-3 * n))


def _parabola(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Sub-pixel offset of the vertex of the parabola through (-1, a), (0, b), (1, c), within +-0.5."""
    denom = a - 2 * b + c
    safe = np.where(np.abs(denom) > 1e-9, denom, -1.0)
    return np.clip(0.5 * (a - c) / safe, -0.5, 0.5)
