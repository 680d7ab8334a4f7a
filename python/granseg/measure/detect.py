"""Find every sphere in an image of the packed bed, centres to a few tenths of a pixel.

Learning, once per run (:func:`learn_templates`): OpenCV's Hough circle
transform and a blob detector, run where a sphere is about 28 px across on a
locally contrast-normalised copy (dark spheres count as much as bright ones),
propose spheres generously; circles fitted to their outlines confirm them,
once with spheres taken as brighter than their surroundings and once as
darker, and the polarity whose confirmed spheres look like it wins
(:func:`_polarity`; from then on the grey image is inverted when spheres are
darker, so that every later step sees bright spheres). In a run's first
frame, stratified, each material's band may learn a polarity of its own
(transparent glass is dark inside, matte POM bright); then each material has
its own template, searched for on its own image, and of two candidates
closer than a sphere only the better match stays. A material that seeds
badly in either polarity (mirror steel) may instead learn its template from
where the other material's template finds it, and its spheres are then
placed by that template's best match rather than by their outline
(:func:`_borrowed`). The mean patch of
each colour group of confirmed spheres is a first template
(:mod:`granseg.measure.templates`). Those spheres are found again with it and
refined as every frame's are, and the final templates are cut around the
refined centres. Last, the confirmed spheres' outlines tell where each
group's edge finder misses the rim on some side (a shaded limb: :func:`_ray_bias`,
taken off in every fit from then on), and how sharp a sphere's rim must be
(:func:`_rim_limits`). Then each group's template learns how its look
changes across the view, from the spheres it finds (lamps beside the camera
light the spheres near the window's sides from the side:
:func:`granseg.measure.templates.with_columns`). Last, a group whose outline
fit does not hold a sphere's place (transparent glass: the fit ends where it
is started) has its template centred where its spheres' mean look is
symmetric, if the spheres the fit does hold show lamps on both sides, level
with the camera (:func:`_symmetric_where_unheld`), and each of its spheres is
then moved up or down to where its own look is symmetric top to bottom
(:func:`_y_by_own_symmetry`); and under such side lamps
the groups the fit holds are placed across the view by a circle of the
nominal size, which cannot hug the lit limb as a circle free in size does
(:func:`_nominal_where_side_lit`).

Every frame (:func:`detect_particles`): the candidates are the matches of
the templates over the sphere disk, each given the group its colour belongs
to, and each is placed by a robust circle fit to its outline
(:mod:`granseg.measure.outline`; a borrowed group's spheres where their
template matches best); a candidate is a sphere if its outline is a sharp
rim at the sphere's size around at least half of it, as sharp as its
group's confirmed spheres' within their scatter (:func:`_examine`):
background, gaps, a free surface and smaller spheres are not; nor is a
sphere with more than a third of its outline outside the image. Under side
lamps, the spheres of a group the fit does not hold take their y from where
their own look is symmetric (:func:`_y_by_own_symmetry`), and those of the
groups it holds their x from the nominal circle (:func:`_x_by_nominal_circle`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from granseg.measure.layers import nearest_spacing
from granseg.measure.outline import N_FIT_RAYS, Outlines, fit_outlines, outline_bias, refine_circles
from granseg.measure.templates import (
    Templates,
    build_templates,
    cut_patches,
    find_spheres,
    join_templates,
    keep_apart,
    recentred,
    with_columns,
)

__all__ = ["Templates", "detect_particles", "learn_templates", "to_gray"]

HOUGH_DIAMETER_PX = 28.0  # Hough runs at a scale where spheres are about this wide
SMOOTH_SIGMA_PX = 0.5  # blur of the grey image that detection works on [px]
# A candidate is a sphere only if its rim score (_examine) is at most RIM_SD
# robust standard deviations (1.4826 MAD) below the median of its group's
# confirmed spheres. Measured in those units against the first frame's
# limits: real spheres reach -5 (black beads on a backlight, 1 in 3000 below
# -4; the synthetic scenes' spheres stay above -4: the score's lower tail
# is heavier than a normal one's, hence not 3-4); background, gaps, the free
# surface and 4 mm beads among 6 mm ones all lie below -10 (synthetic: the
# lid above the bed below -19). Spheres cut by the image border fall from 0
# to below -10 the more of their rim is outside.
RIM_SD = 7.0
# ... and never less than RIM_FLOOR below it: a factor 8 in sharpness. On
# rendered looks the first frame's rims are so alike (MAD ~0.1) that 7 MADs
# is a factor 2, and spheres smeared by the plate's motion (issue 9: half a
# diameter in one exposure) or blurred by video compression fell below it
# (recall 0.93-0.95); background, gaps, the free surface and smaller beads
# score e^5 or more below the spheres, so a factor 8 keeps them out.
RIM_FLOOR = float(np.log(8.0))
# A sphere whose centre lies less than INSIDE_RADII radii inside the image
# has more than a third of its outline outside it (arccos(0.5) / pi): its rim
# score can still pass, on what is left, but its centre is a guess
# along the missing side. On the real photographs these were every false
# detection (15 in ten frames, at the bottom edge: centres 2.4-3.9 px inside,
# beads whose true centres lie outside the image). Frames of a run are
# cropped with a diameter's margin around the window, so no counted sphere
# is near a crop's edge.
INSIDE_RADII = 0.5
# A set of templates learned from the other material's matches (_borrowed)
# is kept only if the spheres it finds in the first frame pack like a bed
# (_packing). Physically based packings: truth 0.965-0.985 d; the borrowed
# steel sets 0.968-0.982 d; every glass set and steel of its own polarity
# 0.82-0.93 d. Set on the tuning packings, where the borrowed steel sets
# packed at 0.974-0.975 d and the best glass set at 0.92 d.
PACKED_NN = 0.95
# ... and packs within PACKING_TIE of the best other set. The one-polarity set
# of a look with mirror steel or glass packs differently on two machines by up
# to 0.015 d (OpenCV's kernels differ in the last bits, and a candidate on the
# edge of the search goes one way or the other), the borrowed sets by 1e-7 d;
# a lead smaller than that is no evidence. Steel over POM packs its borrowed
# set 0.0013 d below one polarity on one machine and 0.0011 d above on another
# (the fixture, 2026-11-29), and its map met the targets only with the borrowed
# set (c_raw RMSD 0.023 against 0.058).
PACKING_TIE = 0.02
# A band's two polarities tie (_ties) where their contrasts (_contrasts)
# differ by less than this share of their sizes' sum; then both are tried
# (_choose_templates). Transparent glass nearly ties: 0.01-0.25 over 31
# physically based glass bands (benches/bench_polarity_ties.py), within 0.05
# on three, bright the stronger by 0.01 on one (ceramic-glass at seed offset
# 300), where glass searched bright gave recall 0.70 and counts 17 % off.
# Every other band is 0.09 or more from a tie: the matte and steel bands of
# the physically based looks 0.15 or more, those of the 2-D renderer 0.09
# (steel under JPEG) or more, over 194 bands of every scene (seeds 7-8 or
# 7-9) and of five POM and steel scenes under each combined change (seed 7).
# Relative, as a dimmer exposure shrinks both contrasts: 2-D POM dimmed to
# 0.6 under MPEG-4 is 4.9 grey levels from a tie, but 0.18 of its contrasts'
# sum.
POLARITY_TIE = 0.05
# How much better [|log| of the spheres-per-row ratio] a set of templates
# resting on a tie's weaker polarity must balance the bands than one on the
# stronger polarities (_choose_templates). Set on glass's ties made to tip
# (benches/bench_polarity_ties.py: the first frame's glass band's two
# contrasts swapped to a tie, on 18 packings of ceramic-glass, glass-pom and
# glass-pp): the right set (glass dark) balanced the bands better than the
# one-polarity set by 0.056-0.48 on 16, by 0.001 and 0.022 on two, where the
# tip then stands, as it did before ties were tried. Glass searched bright
# beside dark steel, wrongly, balanced them better by 0.015-0.019 (a tie of
# 5 grey levels made it a candidate). Requiring the spheres to pack better
# instead would have kept the right set on 9 of the 16 tips it was tried on.
TIE_BALANCE = 0.05
# How much sharper [log units] the rims of a set's candidates must be than one
# polarity's, in the band where the set gives the other sign, for the rims to
# decide between them (_choose_templates, _kept): a sphere found in its own
# polarity has a sharp outline at its size, a gap or a rim found instead has
# none. Set on the choices the physically based glass packings offer
# (benches/bench_polarity_ties.py: seed offsets 100-900, the fixtures, as
# learned and with glass's tie made to tip): the set with glass dark was
# sharper by 0.29-0.81 on every one of 57 choices, where balance and packing
# each failed somewhere; mirror steel, which looks like a sphere in neither
# polarity, differs by -0.26 to +0.34, so the rims do not decide for it.
RIM_CLEAR = 0.35
MIN_CONFIRMED = 30  # confirmed spheres a group needs for rim limits of its own (median and MAD of fewer are noisy)
# Rounds of learning a group's outline bias (_ray_bias): the first refit
# shows what the first estimate left. Two and three rounds gave the same
# maps within noise on the tuning looks (an iteratively reweighted version
# of the fit: 2-D apparatus scenes, seeds 7-8, per-frame layer counts 2.16 /
# 2.19 %).
BIAS_ROUNDS = 2
COLUMN_ROUNDS = 2  # learnings of the look across the view (learn_templates)
# A group whose outline fit does not hold a sphere's place follows where it
# is started: started a tenth of a diameter above and below, its fits end
# more than FOLLOWS of that apart (median over the first frame's spheres).
# Physically based tuning packings: transparent glass 0.63-0.64, every matte
# group 0.00-0.13; 2-D renderer, every group of seeds 7-8 0.00-0.07 (0.33
# for the ten PP spheres of C-PP-90 seed 8, fewer than MIN_CONFIRMED), but
# 0.59-0.69 on one blurred group of four scenes with the dim+noisy+soft
# changes (benches/bench_glass_centring.py; BENCHMARKS.md, "Glass placed
# where its look is symmetric"). Such a group's spheres end near where its
# template's match starts them, so its template is centred where the
# spheres' mean look is symmetric (:func:`_symmetric_where_unheld`), where
# the lamps allow it (TURN, LEVEL).
FOLLOWS = 0.5
# Symmetry places a sphere right only where the lamps light the spheres
# symmetrically: lamps beside the camera on both sides, level with it. The
# spheres the fit does hold tell. Lamps on both sides light the spheres near
# the view's left side on their left and those near its right side on their
# right: the brightness centroid of a held group's mean look moves by more
# than TURN radii from the left third of the view to the right third
# (physically based tuning packings, every matte group: 0.55-0.63; 2-D
# renderer, lamps above, one lamp to the left, diffuse light, blurred: 0.04
# at most). Level lamps leave its mean look symmetric about its fitted
# centres within LEVEL diameters (physically based tuning packings: 0.013 at
# most, both ways; BENCHMARKS.md, as above and "One search for the most
# symmetric line").
TURN = 0.2
LEVEL = 0.03
# Iterations of the nominal circle's fit (_x_by_nominal_circle), started where
# the free circle ended: two gave the maps of three within 0.002 in c_raw RMSD
# on the physically based tuning packings, one moved them by up to 0.010
# (benches/bench_pbr_looks.py; BENCHMARKS.md, "Side-lit spheres placed across
# the view by a circle of their size"). Each costs a fit of the held spheres.
NOMINAL_ITERATIONS = 2
HELD_ROUNDS = 2  # re-centrings of an unheld group's template, each on the spheres the last one found
SYMMETRY_ROUNDS = 3  # re-cuts of the mean look (_centre_of_symmetry): the first moves it most of the way
SYMMETRY_SPAN = 0.2  # how far [d] from the template's middle the centre of symmetry may lie
SYMMETRY_STEP_PX = 0.25  # a re-cut moving the mean look's centre less than this ends the rounds
# Each sphere of a group the fit does not hold (FOLLOWS), its template so
# centred, is then moved up or down, within OWN_SYMMETRY_SPAN d, to where its
# own look is most symmetric top to bottom
# (_y_by_own_symmetry): the template's centring takes off the group's mean
# offset, this each sphere's own. Physically based tuning packings, the glass
# of glass-pom and glass-pp: median |dy| 0.050-0.055 -> 0.016-0.020 d in the
# stratified first frame, 0.018-0.030 -> 0.010-0.019 d in the mixed ones; the
# count error averaged over layer grids shifted by twentieths of a layer
# 6.7 -> 6.2 % and 7.0 -> 6.4 % (spans of 0.05 and 0.15 d did about as well).
# Not left to right: lamps at the sides make an off-centre sphere's look
# lopsided that way (the same move in x left the median |dx| as it was and
# its 90th percentile worse, 0.05-0.06 -> 0.08-0.09 d). BENCHMARKS.md, "Each
# glass sphere centred where its own look is symmetric".
OWN_SYMMETRY_SPAN = 0.1


def to_gray(image: np.ndarray) -> np.ndarray:
    """Luminance of a BGR (or already grey) uint8 image, as float32 in [0, 255]."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image.astype(np.float32)


def _smooth(image: np.ndarray, d: float, signs=(1,)) -> dict[int, np.ndarray]:
    """Grey image with a light blur against noise, by sign: spheres of that polarity bright.

    A sign is a polarity of the spheres (:attr:`Templates.signs`): -1
    (spheres darker than their surroundings) gives the inverted image, so
    that everything downstream (template match, outline fit) sees bright
    spheres.

    No more than 0.5 px: blur pulls the outline edge found on a sphere's
    shadowed side inwards (its shading falls towards the edge), and so
    shifts centres towards the lamp (measured: ceramic under a side lamp
    0.23 px up at 0.95 px blur, 0.17 px at 0.5 px, 0.42 px at 1.5 px).
    """
    blur = cv2.GaussianBlur(to_gray(image), (0, 0), SMOOTH_SIGMA_PX)
    return {int(s): blur if s > 0 else 255.0 - blur for s in set(np.asarray(signs).tolist())}


def _polarity(image: np.ndarray, candidates: dict[int, np.ndarray], d: float) -> tuple[int, np.ndarray]:
    """Whether the spheres are brighter (+1) or darker (-1) than their surroundings, and their seeds
    (+1 and no seeds if neither polarity confirms 3): the polarity of the larger contrast
    (:func:`_contrasts`)."""
    ranked = _contrasts(image, candidates, d)
    return (ranked[0][1], ranked[0][2]) if ranked else (1, np.zeros((0, 4)))


def _band_polarities(image: np.ndarray, candidates: dict[int, np.ndarray], d: float) -> list[tuple[int, np.ndarray]]:
    """A band's polarities (sign, seeds), best first: the polarity of the larger contrast
    (:func:`_contrasts`), and the other too if the two tie (:func:`_ties`; none if neither
    polarity confirms 3 seeds)."""
    ranked = _contrasts(image, candidates, d)
    return [(sign, seeds) for contrast, sign, seeds in ranked[:1]] + \
        [(sign, seeds) for contrast, sign, seeds in ranked[1:] if _ties(ranked[0][0], contrast)]


def _ties(stronger: float, weaker: float) -> bool:
    """Whether two polarities' contrasts (grey levels) differ by less than POLARITY_TIE of their
    sizes' sum (relative, so that a dimmer exposure, which shrinks both, does not make a tie)."""
    return stronger - weaker < POLARITY_TIE * (abs(stronger) + abs(weaker))


def _contrasts(image: np.ndarray, candidates: dict[int, np.ndarray], d: float) -> list[tuple[float, int, np.ndarray]]:
    """Per polarity confirming at least 3 seeds, (contrast, sign, seeds), the largest contrast first.

    The outline fit looks for an outward drop: on the image of either sign
    it confirms circles, centred on the spheres in both cases (on the wrong
    sign the edge it finds is the neighbour's or the background's, further
    out). What tells the signs apart is the mean patch of each sign's seeds:
    the sphere's disk (within 0.8 radii) against its annulus (1-1.5 radii).
    Both signs' seeds sit on the spheres, so both mean patches show the
    spheres' own contrast, the right sign's more clearly (measured, disk -
    annulus grey levels for sign +1 / -1 seeds: black beads on a backlight
    -3 / -98; the six synthetic scenes +35 to +82 / +2 to +37). So the sign
    s with the largest s x contrast wins: no threshold, and a margin of at
    least 85 grey levels on all seven. Transparent glass is the exception
    (dark inside, its rim bright: both signs' seeds find a sphere's look),
    where the two contrasts nearly tie (POLARITY_TIE).
    """
    blur = _smooth(image, d)[1]  # inverted below for sign -1, as _smooth would
    half = int(np.ceil(0.75 * d))
    size = 2 * half + 1
    yy, xx = np.mgrid[0:size, 0:size] - half
    rho = np.hypot(xx, yy) / (0.5 * d)
    disk, annulus = rho <= 0.8, (rho >= 1.0) & (rho <= 1.5)
    ranked = []
    for sign in (1, -1):
        if len(candidates[sign]) == 0:
            continue
        seeds = _select(refine_circles(blur if sign > 0 else 255.0 - blur, candidates[sign], d), d)
        if len(seeds) < 3:
            continue
        mean = np.mean([cv2.getRectSubPix(blur, (size, size), (float(x), float(y))) for x, y in seeds[:, :2]],
                       axis=0)
        ranked.append((sign * float(mean[disk].mean() - mean[annulus].mean()), sign, seeds))
    return sorted(ranked, key=lambda r: -r[0])


def learn_templates(image: np.ndarray, particle_diameter_px: float,
                    bands: tuple[tuple[float, float], tuple[float, float]] | None = None) -> Templates | None:
    """Learn the spheres' appearances from one image (None if it shows fewer than 3 spheres): the
    templates :func:`_choose_templates` keeps, then each group's look across the view
    (:func:`granseg.measure.templates.with_columns`), from the spheres they find in ``image``;
    last, which groups the outline fit holds (:func:`_held`) and whether lamps on both sides
    light them (:func:`_side_lit`) decide where the unheld ones are centred
    (:func:`_symmetric_where_unheld`) and whether the held ones take their x from a circle of
    the nominal size (:func:`_nominal_where_side_lit`).

    The look across the view is learned twice, the second time from the
    spheres found with the first: those near the sides that the frame-wide
    templates missed then join in. It comes after the choice of templates
    so that the choice is made as it was without it (the polarities and the
    borrowed sets were settled on the frame-wide templates).
    """
    d = float(particle_diameter_px)
    templates = _choose_templates(image, d, bands)
    if templates is None:
        return None
    smooth = _smooth(image, d, templates.signs)
    across = templates
    for _ in range(COLUMN_ROUNDS):
        across = with_columns(smooth, templates, detect_particles(image, d, across, details=True))
    spheres = detect_particles(image, d, across, details=True)
    fitted, unheld = _held(smooth, spheres, across)
    held = [g for g in fitted if g not in unheld]
    held_spheres = [spheres[spheres[:, 4] == g] for g in held]
    side_lit = _side_lit(image, across, held_spheres)
    across = _symmetric_where_unheld(image, smooth, across, spheres, unheld, held_spheres, side_lit)
    return _nominal_where_side_lit(across, held, side_lit)


def _nominal_where_side_lit(templates: Templates, held: list[int], side_lit: bool) -> Templates:
    """``templates`` with the groups ``held`` by their outline fit placed across the view (x) by a
    circle of the nominal radius, when lamps beside the camera light the spheres from the side
    (``side_lit``, :func:`_side_lit`); unchanged otherwise.

    Under such lamps a matte sphere's limb away from the nearer lamp fades
    into the gaps, and a circle free in size hugs the lit limb: physically
    based tuning packings, centres 1.1-1.5 px outward near the window's
    sides, spheres there counted outside it. A circle of the nominal size
    cannot shrink onto one limb (0.1-0.5 px). Its y is not taken: it left
    the 2-D renderer's spheres, lit from above, up to 0.6 px too low
    (BENCHMARKS.md, "Spheres placed at the nominal radius"), and under the
    side lamps it does not take off the y bias either. The 2-D renderer's
    lamps do not turn its looks across the view, so its maps do not change.
    """
    if not side_lit or not held:
        return templates
    nominal_x = np.zeros(len(templates.patches), dtype=bool)
    nominal_x[held] = True
    return replace(templates, nominal_x=nominal_x)


def _x_by_nominal_circle(smooth: dict[int, np.ndarray], found: np.ndarray, templates: Templates) -> np.ndarray:
    """``found`` (m, >= 5: x, y, radius, correlation, group) with the x of each sphere of a group with
    ``templates.nominal_x`` from a circle of the nominal radius fitted to its outline, started where
    the free circle ended (:func:`_nominal_where_side_lit`)."""
    if templates.nominal_x is None or len(found) == 0:
        return found
    out = found.copy()
    for mine, outlines in _fit_by_sign(smooth, found, templates, templates.nominal_x[found[:, 4].astype(int)],
                                       radius=templates.d / 2, iterations=NOMINAL_ITERATIONS, free_radius=False):
        out[mine, 0] = outlines.centres[:, 0]
    return out


def _fit_by_sign(smooth: dict[int, np.ndarray], found: np.ndarray, templates: Templates,
                 which: np.ndarray | None = None, radius: float | None = None,
                 **fit: Any) -> Iterator[tuple[np.ndarray, Outlines]]:
    """The outline fits of the spheres of ``found`` (m, >= 5: x, y, radius, correlation, group; those
    of the mask ``which``, default all), each on the image where its group's spheres are bright
    (``smooth`` by sign) with its group's ray bias, about its own radius or ``radius`` for all:
    (mask, :class:`~granseg.measure.outline.Outlines`) per polarity. ``fit``: fit_outlines' options."""
    group = found[:, 4].astype(int)
    sign = templates.signs[group]
    which = np.ones(len(found), bool) if which is None else which
    for s in np.unique(sign[which]):
        mine = which & (sign == s)
        bias = None if templates.ray_bias is None else templates.ray_bias[group[mine]]
        radii = found[mine, 2] if radius is None else np.full(mine.sum(), radius)
        yield mine, fit_outlines(smooth[int(s)], found[mine, :2], radii, templates.d, ray_bias=bias, **fit)


def _held(smooth: dict[int, np.ndarray], spheres: np.ndarray, templates: Templates) -> tuple[list[int], list[int]]:
    """The groups placed by their outline fit with at least MIN_CONFIRMED of ``spheres`` (m, >= 5: x, y,
    radius, correlation, group; the image's grey by sign: ``smooth``), and those of them whose fit
    follows where it is started (:func:`_follows`, over FOLLOWS). Mirror steel placed by a borrowed
    template (``by_match``) is neither."""
    fitted = [g for g in range(len(templates.patches))
              if not (templates.by_match is not None and templates.by_match[g])
              and (spheres[:, 4] == g).sum() >= MIN_CONFIRMED]
    unheld = [g for g in fitted
              if _follows(smooth[int(templates.signs[g])], spheres[spheres[:, 4] == g], templates, g) > FOLLOWS]
    return fitted, unheld


def _symmetric_where_unheld(image: np.ndarray, smooth: dict[int, np.ndarray], templates: Templates,
                            spheres: np.ndarray, unheld: list[int], held: list[np.ndarray],
                            side_lit: bool) -> Templates:
    """``templates`` with each group whose outline fit follows where it is started (``unheld``, found by
    :func:`_held` among ``spheres``, those found in ``image`` with ``templates``) centred where the
    mean look of its spheres (grey by sign: ``smooth``) is symmetric (:func:`_centre_of_symmetry`),
    in HELD_ROUNDS rounds: the spheres found again with the re-centred template are fitted from
    there, and what the fit kept of where the old template put them is taken off in the next round.
    ``held``: the spheres of each group the fit holds; ``side_lit``: whether they show lamps on
    both sides (:func:`_side_lit`).

    Transparent glass under lamps beside the camera shows no rim the fit can
    hold to: its edges are the lamps' reflections and the refracted image
    of what lies behind it, and the fit ends near where it starts. Its
    templates, cut around fitted centres, then keep whatever offset the first
    seeds had (physically based glass-pp and glass-pom, tuning packings:
    the glass found 2.9-3.7 px high on average; started at the true
    centres, the fit stays within 0.3 px of them). The mean look of a sphere
    over the whole view is symmetric about its centre, top to bottom and left
    to right, when the lamps stand level with the camera on both sides, as
    the physically based looks' panels do; the groups the fit holds show
    whether they do (:func:`_level`). With lamps above, the mean look is
    brighter on top and its centre of symmetry lies high: blurred matte
    spheres under the 2-D renderer's lamps follow their start too, and were
    moved up, and their counts made worse, before that gate. Mirror steel
    placed by a borrowed template (``by_match``) keeps that template's centre
    (its fit keeps all of a displaced start). Where the lamps are level top to
    bottom, the group is also marked ``symmetric_y``: the template's centring
    takes off the group's mean offset, :func:`_y_by_own_symmetry` each
    sphere's own.
    """
    d = templates.d
    if not unheld:
        return templates
    level = _level(smooth, templates, held) if side_lit else (False, False)
    for round_ in range(HELD_ROUNDS if any(level) else 0):
        if round_:
            spheres = detect_particles(image, d, templates, details=True)
        for g in unheld:
            mine = spheres[spheres[:, 4] == g, :2]
            if len(mine):
                seen = smooth[int(templates.signs[g])]
                shift = [_centre_of_symmetry(seen, mine, templates, axis) if level[axis] else 0.0 for axis in (0, 1)]
                templates = recentred(templates, g, shift)
    if not level[1]:
        return templates
    symmetric_y = np.zeros(len(templates.patches), dtype=bool)
    symmetric_y[unheld] = True
    return replace(templates, symmetric_y=symmetric_y)


def _y_by_own_symmetry(smooth: dict[int, np.ndarray], found: np.ndarray, templates: Templates) -> np.ndarray:
    """``found`` (m, >= 5: x, y, radius, correlation, group) with each sphere of a group with
    ``templates.symmetric_y`` moved up or down, within OWN_SYMMETRY_SPAN diameters, to where its own
    look (grey by sign: ``smooth``) is most symmetric top to bottom."""
    if templates.symmetric_y is None or len(found) == 0:
        return found
    group = found[:, 4].astype(int)
    marked = templates.symmetric_y[group]
    out = found.copy()
    for sign in np.unique(templates.signs[group[marked]]):
        mine = marked & (templates.signs[group] == sign)
        out[mine, 1] += _mirror_shift(smooth[int(sign)], found[mine, :2], templates.d, axis=1)
    return out


def _mirror_shift(image: np.ndarray, centres: np.ndarray, d: float, axis: int,
                  span: float = OWN_SYMMETRY_SPAN, pooled: bool = False) -> np.ndarray:
    """For each of ``centres`` (m, 2) [px], how far along ``axis`` (0: x, 1: y) [px] from it, within
    ``span`` d, the patch of ``image`` about it is most symmetric: mirrored about the line across
    that axis, the correlation over a disk of 0.55 d about the line's middle. The lines are tried
    every half pixel, where mirroring moves whole pixels (no resampling), and the best refined by a
    parabola through it and its neighbours. ``pooled``: one shift (shape (1,)) for the mean of the
    patches instead."""
    reach = span * d  # [px]
    radius = 0.55 * d
    half = int(np.ceil(radius + reach)) + 1
    patches = cut_patches(image, centres, 2 * half + 1)
    if pooled:
        patches = patches.mean(axis=0, keepdims=True)
    if axis == 0:
        patches = patches.transpose(0, 2, 1)  # mirror rows in either case
    steps = np.arange(-np.floor(2 * reach), np.floor(2 * reach) + 1) / 2
    offsets = np.arange(2 * half + 1) - half
    along, across = np.meshgrid(offsets, offsets, indexing="ij")
    score = np.empty((len(steps), len(patches)))
    for k, step in enumerate(steps):
        rows, cols = np.nonzero((along - step) ** 2 + across ** 2 <= radius ** 2)
        a = patches[:, rows, cols]
        b = patches[:, (2 * (half + step) - rows).astype(int), cols]  # the same pixels, mirrored
        a = a - a.mean(axis=1, keepdims=True)
        b = b - b.mean(axis=1, keepdims=True)
        score[k] = (a * b).sum(axis=1) / np.maximum((a * a).sum(axis=1), 1e-12)
    best = np.argmax(score, axis=0)
    inner = np.clip(best, 1, len(steps) - 2)
    left, mid, right = (score[inner + k, np.arange(len(patches))] for k in (-1, 0, 1))
    curve = left - 2 * mid + right
    vertex = np.where(curve < 0, 0.5 * (left - right) / np.where(curve < 0, curve, -1.0), 0.0)
    refined = steps[inner] + 0.5 * np.clip(vertex, -0.5, 0.5)
    return np.where(best == inner, refined, steps[best])


def _side_lit(image: np.ndarray, templates: Templates, held: list[np.ndarray]) -> bool:
    """Whether lamps on both sides of the camera light the spheres in ``image``, read from ``held``,
    the spheres (m, >= 5: x, y, radius, correlation, group) of each group the outline fit holds:
    every such group's look turns across the view by more than TURN (:func:`_turn`). False without
    such a group."""
    grey = _smooth(image, templates.d)[1]
    return bool(held) and all(_turn(grey, mine[:, :2], templates) > TURN for mine in held)


def _level(smooth: dict[int, np.ndarray], templates: Templates, held: list[np.ndarray]) -> tuple[bool, bool]:
    """Whether side lamps (:func:`_side_lit`) stand level with the camera, left to right and top to
    bottom: in each direction, every group the outline fit holds (``held``, its spheres (m, >= 5))
    shows a mean look (grey by sign: ``smooth``) symmetric within LEVEL diameters of its fitted
    centres."""
    return tuple(all(abs(_centre_of_symmetry(smooth[int(templates.signs[int(mine[0, 4])])], mine[:, :2],
                                             templates, axis)) <= LEVEL * templates.d for mine in held)
                 for axis in (0, 1))


def _turn(grey: np.ndarray, centres: np.ndarray, templates: Templates) -> float:
    """How far [radii] the brightness centroid of the spheres' mean look in ``grey`` moves to the right
    from those in the left third of their x range to those in its right third (NaN if either
    holds fewer than 5): lamps beside the camera light the spheres at each side from that side."""
    size = 2 * templates.half + 1
    yy, xx = np.mgrid[0:size, 0:size] - (size - 1) / 2
    disk = np.hypot(xx, yy) <= 0.5 * templates.d
    lo, hi = centres[:, 0].min(), centres[:, 0].max()
    third = (hi - lo) / 3
    centroid = []
    for side in (centres[centres[:, 0] < lo + third], centres[centres[:, 0] > hi - third]):
        if len(side) < 5:
            return float("nan")
        mean = cut_patches(grey, side, size).mean(axis=0)
        light = np.clip(mean - np.percentile(mean[disk], 10), 0, None) * disk
        centroid.append(float((light * xx).sum() / max(light.sum(), 1e-9)) / (0.5 * templates.d))
    return centroid[1] - centroid[0]


def _follows(image: np.ndarray, spheres: np.ndarray, templates: Templates, group: int) -> float:
    """How much of a vertical displacement of its start the outline fit keeps: the median, over
    ``spheres`` (m, >= 3: x, y, radius) of ``group``, of the distance between the fits started 0.1 d
    above and below the sphere, over 0.2 d (0: the fit comes back; 1: it stays where started)."""
    d = templates.d
    bias = None if templates.ray_bias is None else templates.ray_bias[np.full(len(spheres), group)]
    ends = []
    for dy in (-0.1 * d, 0.1 * d):
        start = spheres[:, :2] + [0.0, dy]
        ends.append(fit_outlines(image, start, spheres[:, 2], d, ray_bias=bias).centres[:, 1])
    return float(np.median((ends[1] - ends[0]) / (0.2 * d)))


def _centre_of_symmetry(image: np.ndarray, centres: np.ndarray, templates: Templates, axis: int = 1) -> float:
    """How far below ``centres`` (m, 2) [px] the spheres' mean look in ``image`` is most symmetric top to
    bottom [px], within SYMMETRY_SPAN d (:func:`_mirror_shift` of the mean patch); re-cut about the
    best line SYMMETRY_ROUNDS times (the mean patch of scattered centres is blurred; once re-cut it
    is less). ``axis=0``: how far right of them it is most symmetric left to right."""
    total = 0.0
    for _ in range(SYMMETRY_ROUNDS):
        step = float(_mirror_shift(image, centres + np.eye(2)[axis] * total, templates.d, axis,
                                   span=SYMMETRY_SPAN, pooled=True)[0])
        total += step
        if abs(step) < SYMMETRY_STEP_PX:
            break
    return total


def _choose_templates(image: np.ndarray, d: float,
                      bands: tuple[tuple[float, float], tuple[float, float]] | None = None) -> Templates | None:
    """The frame-wide templates of one image (None if it shows fewer than 3 spheres).

    ``bands``: two row ranges (top, bottom) [px] of ``image`` each known to
    hold the centres of spheres of one material only (the first frame of a
    run, stratified about its interface). If both are at least a diameter
    tall, each band's polarity is then learned apart as well.
    Where they differ, further sets are learned: each material's of its own
    polarity, and for each band one whose material is learned from the
    spheres the other band's template finds there (:func:`_borrowed`). A
    borrowed set is kept if the spheres it finds in both bands pack like a
    bed, and no worse than those of the other sets (:func:`_lent`); otherwise
    the set whose candidates show clearly sharper rims where the sets differ
    is kept (:func:`_kept`), and failing that the set
    of each material's own polarity,
    unless with one polarity the two bands' spheres per row come out closer
    (:func:`_band_imbalance`) and pack closer too. Transparent glass (dark
    inside, its rim bright) above matte POM (bright on dark gaps) has no
    polarity that suits both: with one, the glass of the first frame was
    found 25 times of 64, with its own 61. Measured on the physically based
    tuning packings (spheres per row, the richer band's over the other's, one
    polarity / each its own; c_raw RMSD of the map made with each): glass-pom
    1.40 / 1.10 (0.22 / 0.09), glass-pp 1.41 / 1.03 (0.10 / 0.06), steel-pom
    1.04 / 1.08 (0.03 / 0.07), steel-pp 1.014 / 1.013 (0.21 / 0.14). For
    mirror steel neither was right; the steel learned from the matte
    material's matches is (packing, the worse band's median nearest-neighbour
    distance [d], one polarity / each its own / borrowed: steel-pp 0.918 /
    0.928 / 0.974, steel-pom 0.961 / 0.867 / 0.975; c_raw RMSD 0.135 -> 0.052
    and 0.031 -> 0.027). The glass looks' borrowed sets pack no better than
    0.92 and are not kept (BENCHMARKS.md).

    A band whose two polarities' contrasts tie (POLARITY_TIE: transparent
    glass) offers both, and each pair of differing band polarities gives a
    set of each material's own; one that rests on the tie's weaker polarity
    is kept only if it balances the bands better by TIE_BALANCE
    (glass beside ceramic, both searched bright where glass's tie tipped:
    recall 0.70 and counts 17 % off; glass searched dark as well, recall
    0.99, counts 4.2 %).

    The final templates are cut around the confirmed spheres as
    :func:`detect_particles` places them, so that a template's middle is, on
    average, where the outline fit puts a sphere and a match starts the fit
    within its scatter (the first templates' centres, from the mean patch
    alone, were up to 2 px off for dark POM, from where the fit sometimes
    went astray; issue 3).
    """
    candidates = _candidates(to_gray(image), d)
    sign, seeds = _polarity(image, candidates, d)
    one = _with_rims(image, _templates_from_seeds(image, seeds, d, sign), seeds) if len(seeds) >= 3 else None
    if bands is None or min(bottom - top for top, bottom in bands) < d:
        # a band less than a diameter tall holds at most a part of a row: what it
        # shows (3 gaps between smeared spheres, C-PP-90 with c0 = 0.93, where the
        # light band was 7 px of the plate's edge) is no material's polarity
        return one
    options = [_band_polarities(image, _in_rows(candidates, rows), d) for rows in bands]
    # each band's polarity, the two differing; a band whose two contrasts tie offers both
    pairs = [[a, b] for a in options[0] for b in options[1] if a[0] != b[0]]
    if not pairs:
        return one
    stronger = (options[0][0][0], options[1][0][0])  # each band's polarity of the larger contrast
    guessed = [(a[0], b[0]) != stronger for a, b in pairs]
    splits, borrowed = [], []
    for per_band, guess in zip(pairs, guessed, strict=True):
        own = [_templates_from_seeds(image, seeds, d, sign, one_group=True) for sign, seeds in per_band]
        splits.append(_with_rims(image, join_templates(own), np.concatenate([seeds for _, seeds in per_band])))
        if not guess:  # a material is learned from the other's matches only where both polarities are clear
            borrowed += [b for k in (0, 1) if (b := _borrowed(image, own, per_band, bands, k)) is not None]
    if one is None:  # too few seeds in the whole frame: the bands' own polarities, if they differ
        return next((split for split, guess in zip(splits, guessed, strict=True) if not guess), None)
    sets = [one, *splits, *borrowed]
    spheres, rims = zip(*(_band_spheres(image, t, bands) for t in sets), strict=True)
    packing = [_packing(s, d) for s in spheres]
    if (lent := _lent(packing, len(splits) + 1)) is not None:
        return sets[lent]
    imbalance = [_band_imbalance(s, bands) for s in spheres[:len(splits) + 1]]
    sharper = [_sharper_rims(rims[0], split, sign, per_band)
               for split, per_band in zip(rims[1:len(splits) + 1], pairs, strict=True)]
    return sets[_kept(imbalance, packing[:len(splits) + 1], guessed, sharper)]


def _lent(packing: list[float], n_own: int) -> int | None:
    """The borrowed set kept, if one is (its index in ``packing``, :func:`_packing` per set: the first
    ``n_own`` sets learned from the bands' own polarities, the rest borrowed): the best-packed
    borrowed set, where it packs like a bed (PACKED_NN) and within PACKING_TIE of the best other."""
    if len(packing) <= n_own:
        return None
    lent = n_own + int(np.argmax(packing[n_own:]))
    return lent if packing[lent] >= max(PACKED_NN, max(packing[:n_own]) - PACKING_TIE) else None


def _kept(imbalance: list[float], packing: list[float], guessed: list[bool], sharper: list[float]) -> int:
    """Which set is kept, 0 (one polarity) or i >= 1 (each material's own, ``guessed[i - 1]`` if it
    rests on a tie's weaker polarity), by the sharpness of the rims where they differ (``sharper[i -
    1]``, :func:`_sharper_rims`), the bands' imbalance (:func:`_band_imbalance`) and the spheres'
    packing (:func:`_packing`), each given per set.

    Where a set's rims are sharper than one polarity's by RIM_CLEAR or more,
    it is kept (the sharpest if several); where every set's are blunter by
    as much, one polarity is. A set that finds a material in the polarity
    that suits it finds spheres; one that does not, gaps or rims: over the
    57 choices the physically based glass packings offered, the rims picked
    the set with glass dark every time by 0.29-0.81 (glass searched bright
    beside dark steel, which balanced the bands better: 0.47-0.69 blunter).
    Otherwise, as follows.

    Both bands are packed beds of spheres of one size: templates that find
    each band's spheres find as many per row in both, while a polarity that
    does not suit a material finds its gaps and misses spheres. The bands'
    own polarities are what the frame shows, so one polarity for both
    overrides them only if its spheres balance the bands better and pack
    better too: glass searched bright beside ceramic can balance them by
    finding glass's gaps (seed offset 600: 1.070 spheres per row against
    1.138 for glass dark; glass recall 0.07), but packs worse (0.856 against
    0.892). A set resting on a tie's weaker polarity must balance the bands
    better by TIE_BALANCE than every set on the stronger polarities.
    """
    sharp = [i for i, gain in enumerate(sharper, start=1) if gain >= RIM_CLEAR]
    if sharp:
        return max(sharp, key=lambda i: sharper[i - 1])
    if sharper and all(gain <= -RIM_CLEAR for gain in sharper):
        return 0
    clear = [i for i, guess in enumerate(guessed, start=1) if not guess]  # at most one: the stronger polarities
    chosen = next((i for i in clear if not (imbalance[0] < imbalance[i] and packing[0] > packing[i])), 0)
    best_clear = min(imbalance[i] for i in [0, *clear])
    guesses = [i for i, guess in enumerate(guessed, start=1) if guess and imbalance[i] + TIE_BALANCE < best_clear]
    return min(guesses, key=imbalance.__getitem__) if guesses else chosen


def _borrowed(image: np.ndarray, own: list[Templates], per_band: list[tuple[int, np.ndarray]], bands,
              k: int) -> Templates | None:
    """Templates whose band ``k`` material is learned from the spheres the other band's template finds
    in band ``k`` (None if it finds fewer than 3 there); that material's spheres are placed where its
    template matches best (``by_match``).

    ``own``: each band's templates from its own seeds; ``per_band``: each
    band's polarity and seeds. Mirror steel is seeded off its spheres in
    both polarities, and its template and outline fits inherit the error
    (physically based steel-pp, tuning packing: every steel sphere of the
    first frame found a third of a diameter too high), while matte PP's
    template, which has never seen steel, finds 97 % of it within a tenth
    of a diameter where it matches best (the PP outline fit, made for PP,
    scatters them by 1.7 px). The steel template cut around those matches
    then places steel spheres by its best match within 0.3-0.5 px sd (0.6-1
    px high); their outline fit scatters by 1.5 px, as the rim of a mirror
    sphere is the reflection of its neighbours. A matte template's mean
    patch of steel makes the best template for it: the match positions it
    was cut around gave c_raw RMSD 0.027 on the tuning steel-pom, the
    outline-fitted ones 0.047.
    """
    sign, seeds = per_band[1 - k]
    lender = replace(_with_rims(image, own[1 - k], seeds), by_match=np.array([True]))
    top, bottom = bands[k]
    found = detect_particles(image, lender.d, lender)
    found = found[(found[:, 1] >= top) & (found[:, 1] <= bottom)]
    if len(found) < 3:
        return None
    smooth = _smooth(image, lender.d, (sign,))
    learned = replace(build_templates(smooth[sign], image, found[:, :2], lender.d, centred=True, sign=sign,
                                      one_group=True), by_match=np.array([True]))
    parts, confirmed = ([learned, own[1]], [found, per_band[1][1]]) if k == 0 else \
        ([own[0], learned], [per_band[0][1], found])
    return _with_rims(image, join_templates(parts), np.concatenate([c[:, :4] for c in confirmed]))


def _sharper_rims(one: list[dict[int, float]], split: list[dict[int, float]], sign: int,
                  per_band: list[tuple[int, np.ndarray]]) -> float:
    """How much sharper [log units] the rims of a set of each material's own polarity (``per_band``: each
    band's sign and seeds) are than those of one polarity ``sign``, in the band where its sign differs
    (``one``, ``split``: each set's rims by band from :func:`_band_spheres`); nan where either finds no candidate there."""
    k = next(k for k, (s, _) in enumerate(per_band) if s != sign)
    return split[k].get(per_band[k][0], np.nan) - one[k].get(sign, np.nan)


def _band_spheres(image: np.ndarray, templates: Templates, bands) -> tuple[list[np.ndarray], list[dict[int, float]]]:
    """Per band (rows top, bottom): the centres (m, 2) of the spheres ``templates`` find in ``image``,
    and per sign the median rim score (:func:`_examine`) of the candidates of that sign there (a
    sign with none there left out); from one search."""
    smooth = _smooth(image, templates.d, templates.signs)
    found, rim, judged = _examine(smooth, image, templates)
    sign = templates.signs[found[:, 4].astype(int)]
    rims = []
    for top, bottom in bands:
        inside = (found[:, 1] >= top) & (found[:, 1] <= bottom) & np.isfinite(rim)
        rims.append({int(s): float(np.median(rim[inside & (sign == s)]))
                     for s in np.unique(templates.signs) if np.any(inside & (sign == s))})
    placed = _placed(smooth, found, rim, judged, templates, image.shape)
    spheres = [placed[(placed[:, 1] >= top) & (placed[:, 1] <= bottom), :2] for top, bottom in bands]
    return spheres, rims


def _band_imbalance(spheres: list[np.ndarray], bands) -> float:
    """|log| of the ratio of the spheres found per row [1/px] in the two ``bands`` (``spheres`` per band)."""
    density = [max(len(s), 1) / max(bottom - top, 1.0) for s, (top, bottom) in zip(spheres, bands, strict=True)]
    return abs(float(np.log(density[0] / density[1])))


def _packing(spheres: list[np.ndarray], d: float) -> float:
    """The least, over the bands, of the median distance [d] from a sphere to its nearest neighbour
    (0 if a band holds fewer than 3 spheres).

    In a packed bed the spheres at the wall touch their neighbours: the true
    median is 0.965-0.985 d on every physically based look. Detections off
    their spheres bring it down (ghosts between spheres, scattered centres:
    0.82-0.93 d where glass or steel was found off), and so does a template
    that finds a material's gaps as well as its spheres. A common shift of
    one material's centres leaves it unchanged.
    """
    if any(len(s) < 3 for s in spheres):
        return 0.0
    return min(nearest_spacing(s) / d for s in spheres)


def _templates_from_seeds(image: np.ndarray, seeds: np.ndarray, d: float, sign: int,
                          one_group: bool = False) -> Templates:
    """Templates of one polarity from confirmed seeds (m, >= 2): a first set from the seeds, then
    one cut around the seeds found again by it and placed by their outlines."""
    smooth = _smooth(image, d, (sign,))
    first = build_templates(smooth[sign], image, seeds[:, :2], d, sign=sign, one_group=one_group)
    found = find_spheres(smooth, image, first)
    # only confirmed spheres: other matches (at the lid, in voids) would blur the templates
    found = found[_near(found[:, :2], seeds[:, :2], 0.3 * d)]
    if len(found) < 3:
        return first
    refined = fit_outlines(smooth[sign], found[:, :2], found[:, 2], d).centres
    return build_templates(smooth[sign], image, refined, d, centred=True, sign=sign, one_group=one_group)


def _with_rims(image: np.ndarray, templates: Templates, seeds: np.ndarray) -> Templates:
    """``templates`` with what the confirmed ``seeds``' rims tell: each group's outline bias
    (:func:`_ray_bias`), then the limits of "looks like a sphere", from the seeds scored as every
    frame's spheres are (unchanged if fewer than MIN_CONFIRMED)."""
    smooth = _smooth(image, templates.d, templates.signs)
    found, rim, _ = _examine(smooth, image, templates)
    confirmed = _near(found[:, :2], seeds[:, :2], 0.3 * templates.d)
    if np.isfinite(rim[confirmed]).sum() < MIN_CONFIRMED:
        return templates
    templates = replace(templates, ray_bias=_ray_bias(smooth, templates, found[confirmed]))
    found, rim, _ = _examine(smooth, image, templates)
    confirmed = _near(found[:, :2], seeds[:, :2], 0.3 * templates.d)
    if np.isfinite(rim[confirmed]).sum() < MIN_CONFIRMED:
        return templates
    return replace(templates, rim_limits=_rim_limits(rim[confirmed], found[confirmed, 4], len(templates.patches)))


def _ray_bias(smooth: dict[int, np.ndarray], templates: Templates, spheres: np.ndarray) -> np.ndarray | None:
    """Per group (k, N_FIT_RAYS), where the outline fit's edge finder puts each ray's edge outside
    the true outline [px], from ``spheres`` (m, >= 5: x, y, radius, correlation, group), the
    confirmed spheres of one frame; None if no group has MIN_CONFIRMED of them placed by outline.

    Learned in BIAS_ROUNDS rounds, each refitting the spheres with the bias
    learned so far (:func:`granseg.measure.outline.outline_bias`): with the
    bias taken off, the fit moves and shows what is left of it. One profile
    serves the whole frame: it takes off what a kind of sphere's look does
    to its rim everywhere (the lamps above the 2-D renderer's bed), not the
    bias that turns across the frame with the view (side panels seen off
    the axis, BENCHMARKS.md). Keeping only the part that every half of the
    frame (left, right, top, bottom) agreed on was tried on the tuning
    looks and lost against one profile (2-D apparatus counts 2.38 against
    2.21 %, physically based pom-pp 2.7 against 2.3 %). One profile per
    band of height, against the physically based looks' y bias that grows
    towards the top and bottom, was tried too and moved nothing: a bias
    that shifts a whole side of the outline is a move of the circle, which
    the residuals the profile is read from never hold.
    """
    bias = np.zeros((len(templates.patches), N_FIT_RAYS))
    by_match = np.zeros(len(bias), bool) if templates.by_match is None else templates.by_match
    groups = [g for g in range(len(bias)) if not by_match[g] and (spheres[:, 4] == g).sum() >= MIN_CONFIRMED]
    for g in groups:
        mine = spheres[spheres[:, 4] == g]
        for _ in range(BIAS_ROUNDS):
            fit = fit_outlines(smooth[int(templates.signs[g])], mine[:, :2], mine[:, 2], templates.d,
                               ray_bias=bias[g])
            bias[g] += outline_bias(fit.residual)
    return bias if groups else None


def _in_rows(candidates: dict[int, np.ndarray], rows: tuple[float, float]) -> dict[int, np.ndarray]:
    """The candidates (per polarity, (m, 2) x, y) whose y lies within ``rows`` (top, bottom)."""
    return {sign: c[(c[:, 1] >= rows[0]) & (c[:, 1] <= rows[1])] for sign, c in candidates.items()}


def _near(points: np.ndarray, others: np.ndarray, dist: float) -> np.ndarray:
    """Whether each of ``points`` (m, 2) lies within ``dist`` of one of ``others`` (n, 2)."""
    if len(points) == 0 or len(others) == 0:
        return np.zeros(len(points), dtype=bool)
    return np.hypot(*(points[:, None, :] - others[None, :, :]).transpose(2, 0, 1)).min(axis=1) < dist


def detect_particles(image: np.ndarray, particle_diameter_px: float, templates: Templates | None = None,
                     details: bool = False, smeared_below: float | None = None) -> np.ndarray:
    """Centres and radii of the spheres in ``image``.

    Parameters
    ----------
    image : (H, W, 3) BGR or (H, W) grey uint8 image (undistorted).
    particle_diameter_px : expected sphere diameter [px].
    templates : appearances from :func:`learn_templates` (learned from
        ``image`` itself when None); reuse them across the frames of a run.
    details : also return each sphere's template (appearance group) index and
        how far [px] the outline fit's last iteration moved its centre.
    smeared_below : the row [px] below which spheres may be smeared along x by
        the plate's motion: there a sphere's rim is also judged by its top and
        bottom alone (:func:`rim_scores`). None: nowhere.

    Returns
    -------
    (m, 4) float array: x, y [px, pixel centres at integers], radius [px] and
    the correlation in [-1, 1] of the sphere's disk with its template; (m, 6)
    with the group index and the last step when ``details``.
    """
    d = float(particle_diameter_px)
    if templates is None:
        templates = learn_templates(image, d)
        if templates is None:
            return np.zeros((0, 6 if details else 4))
    smooth = _smooth(image, d, templates.signs)
    found, rim, judged = _examine(smooth, image, templates, smeared_below)
    found = _placed(smooth, found, rim, judged, templates, image.shape)
    return found if details else found[:, :4]


def _placed(smooth: dict[int, np.ndarray], found: np.ndarray, rim: np.ndarray, judged: np.ndarray,
            templates: Templates, shape: tuple[int, ...]) -> np.ndarray:
    """The spheres among a frame's examined candidates (:func:`_examine`'s ``found``, ``rim`` and
    ``judged``, in an image of ``shape``): those whose ``judged`` rim passes, one per place (ranked
    by ``rim``), centred as their group is."""
    if templates.rim_limits is not None:
        passed = judged >= templates.rim_limits[found[:, 4].astype(int)]
        found = _one_per_place(found[passed], rim[passed], templates)
    found = _y_by_own_symmetry(smooth, found, templates)
    return _x_by_nominal_circle(smooth, found[_inside(found, shape)], templates)


def _inside(found: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Whether each sphere's centre (found (m, >= 3): x, y, radius) lies INSIDE_RADII radii or more inside
    an image of ``shape`` (pixel centres at integers: the image spans -0.5 to width - 0.5)."""
    margin = INSIDE_RADII * found[:, 2]
    x, y = found[:, 0], found[:, 1]
    return ((x + 0.5 >= margin) & (shape[1] - 0.5 - x >= margin)
            & (y + 0.5 >= margin) & (shape[0] - 0.5 - y >= margin))


def _one_per_place(found: np.ndarray, rim: np.ndarray, templates: Templates) -> np.ndarray:
    """With groups of both polarities, of spheres closer than 0.7 diameter only one stays: the one
    matching its template best (correlation over its group's median), or, once a group is placed
    by its template's match (``templates.symmetric_y``), the one whose outline is sharpest for its
    group (its ``rim`` score, :func:`_examine`, less its group's median). Unchanged with one
    polarity.

    A gap between three bright spheres is a dark blob whose surroundings
    rise at about a radius, so it can pass as a dark sphere, and the rim of
    transparent glass as a bright one; each lies 0.58 diameter from three
    spheres. Their correlation is about half their group's median, a real
    sphere's about its median (physically based glass-pp, tuning packing:
    the glass of the first frame found 62 of 66 times, against 50 when the
    raw rim score decided).

    Transparent glass's template also matches a matte neighbour 0.3-0.7
    diameter off about as well as it matches glass, and glass, which the
    outline fit does not hold, stays where its match puts it: matte spheres
    were lost to such matches (ceramic-glass fixture: 12 of 215 ceramic
    spheres found as glass 0.3-0.75 d off). Neither such a match nor a gap
    has a sharp rim at the sphere's size; a real sphere has one about as
    sharp as the rest of its group's. So where glass is placed by its
    template the rim relative to its group decides: over the conflicts with
    one candidate on a true sphere, it keeps that one in 93 %, 95 % and 98 %
    on the tuning packings of glass-pom, glass-pp and ceramic-glass, the
    correlation in 83 %, 81 % and 95 %. Not before the templates are final:
    while they are chosen, glass's template is not yet centred, and the rim
    there tipped the glass-pp fixture to one polarity for both materials
    (recall 0.99 -> 0.94). BENCHMARKS.md, "One sphere per place kept by the
    sharpness of its rim".
    """
    if len(np.unique(templates.signs)) < 2 or len(found) == 0:
        return found
    group = found[:, 4].astype(int)
    by_rim = templates.symmetric_y is not None
    score = rim if by_rim else found[:, 3]
    median = np.array([np.median(score[group == g]) if (group == g).any() else 1.0
                       for g in range(len(templates.patches))])
    key = score - median[group] if by_rim else score / median[group]
    return found[np.sort(keep_apart(found[:, :2], np.argsort(-key, kind="stable"), 0.7 * templates.d))]


def _examine(smooth: dict[int, np.ndarray], image: np.ndarray, templates: Templates,
             smeared_below: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every candidate sphere of a frame, placed by its outline, and its rim score twice over.

    Returns found (m, 6: x, y, radius, correlation, group, the outline fit's
    last step [px]) and rim (m,): the
    logarithm of the median, over the outline fit's rays, of the sharpness
    of the edge at the expected radius (0, so -inf, on a ray without a
    falling edge there). It is high only if at least half the rim is a sharp
    outline at the sphere's size: not on a patch of background (no edge), a
    gap between spheres or the free surface (edges of the other sign or at
    other distances), a smaller sphere (its edge well inside the search
    band) or a sphere cut by the image border. A logarithm, because edges
    scale with the lamps: twice the light, twice the sharpness. Below row
    ``smeared_below`` the top and bottom alone may also pass a candidate
    (:func:`rim_scores`), so the third array, judged (m,), is the score the rim
    limits judge; ``rim``, over every ray, ranks candidates
    (:func:`_one_per_place`). Equal to ``rim`` where nothing is smeared.
    """
    found = find_spheres(smooth, image, templates)
    found = np.column_stack([found, np.zeros(len(found))])
    matched = None if templates.by_match is None else found[:, :2].copy()
    rim = np.empty(len(found))
    judged = np.empty(len(found))
    for mine, outlines in _fit_by_sign(smooth, found, templates):
        found[mine, :2] = outlines.centres
        found[mine, 5] = outlines.step
        sideways = None if smeared_below is None else outlines.centres[:, 1] >= smeared_below
        rim[mine], judged[mine] = rim_scores(outlines.strength, sideways)
    if matched is not None:  # placed by their template (learn_templates); the rim still judges them
        by_match = templates.by_match[found[:, 4].astype(int)]
        found[by_match, :2] = matched[by_match]
    return found, rim, judged


def rim_scores(strength: np.ndarray, sideways: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The rim scores (:func:`_examine`) from the edge sharpness of each sphere's rays (m, k; ray i
    at angle 2 pi i / k): the logarithm of the median over every ray, and the score judged: the
    same, but for the spheres ``sideways`` (bool, (m,); None: none) the median over the rays
    within 45 degrees of vertical where that is higher.

    The plate's motion blurs the spheres near it along x, which smears the
    edges of their sides, not of their top and bottom: 80 px steel spheres
    smeared by half a diameter by the plate scored -0.13 to -0.39 over every
    ray (their group's limit -0.13, its median 1.8) and 0.5 to 1.4 over the
    vertical ones, while candidates a diameter off any sphere scored below
    -0.9 both ways (BENCHMARKS.md, "Smeared spheres by the plate"). Only
    where the plate can smear: everywhere, one small bead of the real
    photographs passed as a large one on its top and bottom.
    """
    with np.errstate(divide="ignore"):
        score = np.log(np.median(strength, axis=1))
        if sideways is None or not np.any(sideways):
            return score, score
        k = strength.shape[1]
        vertical = np.abs(np.sin(2 * np.pi * np.arange(k) / k)) > np.sqrt(0.5) + 1e-9  # strictly within
        upright = np.log(np.median(strength[sideways][:, vertical], axis=1))
    judged = score.copy()
    judged[sideways] = np.maximum(score[sideways], upright)
    return score, judged


def _rim_limits(rim: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Per group, the lowest rim score (:func:`_examine`) of a sphere: RIM_SD robust sd (at least
    RIM_FLOOR) below the median.

    Learned from the confirmed spheres of the first frame (median and MAD,
    robust to the few odd ones among them); a group with fewer than
    MIN_CONFIRMED of them takes the limit of all confirmed spheres.
    """
    def limit(x: np.ndarray) -> float:
        x = x[np.isfinite(x)]
        med = float(np.median(x))
        return med - max(RIM_SD * 1.4826 * float(np.median(np.abs(x - med))), RIM_FLOOR)

    pooled = limit(rim)
    return np.array([limit(rim[group == g]) if np.isfinite(rim[group == g]).sum() >= MIN_CONFIRMED else pooled
                     for g in range(n_groups)])


def _candidates(gray: np.ndarray, d: float) -> dict[int, np.ndarray]:
    """Candidate centres (x, y) in full-resolution pixels, per polarity: Hough circles and blobs.

    All run on a locally contrast-normalised copy at reduced scale, so that
    dark spheres (POM) are found as readily as bright ones. The circles
    serve either polarity; the blobs are bright ones for spheres brighter
    than their surroundings (+1), dark ones for darker spheres (-1, black
    beads on a backlight); the other kind are the gaps between spheres.
    """
    scale = min(1.0, HOUGH_DIAMETER_PX / d)
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else gray
    norm = _local_contrast(small, d * scale)
    circles = _hough(norm, d * scale)
    # scaled pixel centres -> full-resolution pixel centres
    return {sign: (np.concatenate([circles, _blobs(norm if sign > 0 else 255 - norm, d * scale)]) + 0.5) / scale - 0.5
            for sign in (1, -1)}


def _local_contrast(img: np.ndarray, d: float) -> np.ndarray:
    """Brightness in units of the local spread over about two diameters, as uint8."""
    mean = cv2.GaussianBlur(img, (0, 0), d)
    var = cv2.GaussianBlur((img - mean) ** 2, (0, 0), d)
    z = (img - mean) / np.sqrt(var + 4.0)
    return np.clip(128 + 50 * z, 0, 255).astype(np.uint8)


def _hough(norm: np.ndarray, d: float) -> np.ndarray:
    r = 0.5 * d
    smooth = cv2.GaussianBlur(norm, (0, 0), 1.0)
    found = cv2.HoughCircles(
        smooth, cv2.HOUGH_GRADIENT, dp=1, minDist=0.45 * d, param1=60, param2=max(6.0, 0.22 * 2 * np.pi * r),
        minRadius=int(np.floor(0.75 * r)), maxRadius=int(np.ceil(1.2 * r)),
    )
    return np.zeros((0, 2)) if found is None else found.reshape(-1, 3)[:, :2].astype(float)


def _blobs(norm: np.ndarray, d: float) -> np.ndarray:
    """Local maxima of a difference of Gaussians tuned to sphere size."""
    img = norm.astype(np.float32)
    dog = cv2.GaussianBlur(img, (0, 0), 0.25 * d) - cv2.GaussianBlur(img, (0, 0), 0.6 * d)
    size = max(3, int(0.5 * d) | 1)
    peaks = (dog >= cv2.dilate(dog, np.ones((size, size), np.uint8))) & (dog > 0)
    ys, xs = np.nonzero(peaks)
    return np.column_stack([xs, ys]).astype(float)


def _select(circles: np.ndarray, d: float) -> np.ndarray:
    """Drop implausible fits, then keep the best circle within 0.7 diameter."""
    ok = (circles[:, 2] > 0.3 * d) & (circles[:, 2] < 0.7 * d) & (circles[:, 4] >= 0.5)
    ok &= np.all(np.isfinite(circles), axis=1)
    circles = circles[ok]
    if circles.size == 0:
        return np.zeros((0, 4))
    quality = circles[:, 3] * circles[:, 4]
    out = circles[keep_apart(circles[:, :2], np.argsort(-quality), 0.7 * d)]
    weak = out[:, 3] * out[:, 4] < 0.25 * np.median(out[:, 3] * out[:, 4])
    out = out[~weak]
    # One size: a bed may hold spheres of another size too (4 mm beads among
    # 6 mm ones: fitted radii 0.68-0.75 of d/2 against 0.95 +- 0.01), which
    # would otherwise make a template group of their own, with the radius of
    # the spheres asked for. Seeds more than 4 robust standard deviations of
    # the seeds' radii from their median are left out; the spread is that of
    # the fits, not of the sizes (0.03-0.09 of d/2 on the synthetic scenes,
    # where the shading moves the steepest drop inwards), so only a distinct
    # population is cut, and a real sphere lost as a seed is still found.
    r = out[:, 2]
    spread = 1.4826 * np.median(np.abs(r - np.median(r)))
    return out[np.abs(r - np.median(r)) <= 4 * spread + 1e-9][:, :4]
