"""Heavy or light: each sphere's appearance, two classes learned from the first frame.

No thresholds are tuned by hand, and no material pair is special-cased. An
experiment starts stratified (docs/model.md): heavy grains above the interface at
height (1 - c0) H, light ones below. The first frame is therefore labelled
training data for free: spheres more than :data:`MARGIN` diameters above the
interface are heavy, those as far below are light. A classifier learned on
them (scikit-learn's logistic regression on standardised features) gives
every sphere of the run a probability of being heavy. A feature is never
standardised by a spread finer than it is measured (:data:`RESOLUTION`), so
that a feature both materials share cannot decide a class on a shift of a
grey level.

Each sphere is described by what sets materials apart when they share a hue
(:data:`FEATURES`): the colour of its middle in CIE LAB, the spread of its
lightness, the strength and size of its specular highlight, how much its rim
darkens, and the fine texture of its surface; the median HSV colour is kept
for explicit colour ranges. Polished steel and dark-grey POM, which differ
in brightness and gloss but hardly in hue, separate on these (issue 9).
Gloss is also read where the first frame's glossy spheres show the lamps
(:func:`learn_spots`), which a speck of dust on the wall does not mimic; the
first frame's cross-validation decides which reading a run keeps. Light
that changes over the view (a lamp above the cell, vignetting) is read off
the labelled spheres too, as what changes smoothly within each class, and
taken off every sphere where it would move the classes (:class:`LightField`).

Because the classes are learned, they can also be *checked*
(:class:`Separation`): how well the labelled spheres are told apart under
cross-validation (two materials that look the same score about one half and
are flagged, never split at random), and whether the learned score follows
the sphere's height within each class (a lighting gradient or the motion blur
of the fast bottom layers mistaken for a material).

Explicit colour ranges in ``experiment.json`` (``heavy_hsv``, ``light_hsv``,
``heavy_lab``, ``light_lab``: [[lo x3], [hi x3]] in OpenCV's 8-bit scales)
override the learning.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from sklearn.linear_model import LogisticRegression
from sklearn.model_selection import StratifiedKFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

__all__ = ["BLUR_ZONE", "FEATURES", "MARGIN", "MARGINS", "RESOLUTION", "SMEARS", "BlurTest", "MaterialClasses",
           "LightField", "ResolvedScaler", "Separation",
           "blur_test", "classify_by_ranges", "interface_labels", "disk_rises", "learn_classes", "learn_spots", "light_field", "smeared_images", "spot_weights",
           "sphere_features"]

FEATURES = ("L", "a", "b", "L_spread", "H", "S", "V",
            "highlight", "highlight_area", "rim", "texture", "specular", "highlight_at_spots")
# the features the learned classes use: LAB colour and the gloss / shape cues
# (not HSV: its hue wraps at red and is noise on grey spheres)
LEARNED = (0, 1, 2, 3, 7, 8, 9, 10, 11)
# The same with gloss read at the learned spots instead of as the disk's
# brightest points. Both maxima take a speck of dust on the wall over a matte
# sphere for a lamp's image on a glossy one; the lamps' images sit at the
# same places on every sphere of a kind, a speck anywhere (:func:`learn_spots`).
# Which of the two a run uses is decided by cross-validation on the first
# frame's labelled spheres (:func:`learn_classes`).
LEARNED_AT_SPOTS = (0, 1, 2, 3, 8, 9, 10, 12)
# Labelled spheres lie this many diameters or more from the initial
# interface: a packing's rows are not flat, and the interface (1 - c0) H is
# where the layers' volumes split, not where every sphere does. When c0 is
# near 0 or 1 one class is a single row, and the margin shrinks (down to
# zero) until both classes have MIN_PER_CLASS spheres.
MARGIN = 0.75
MARGINS = (0.75, 0.5, 0.25, 0.0)
MIN_PER_CLASS = 5  # fewer labelled spheres of a class than this: cannot learn the classes
AMBIGUOUS = (0.2, 0.8)  # a sphere whose p_heavy falls in here is ambiguous

# Sample circles (radius / sphere radius, points). The middle three give the
# colour (as the colour features always did); all of them give the gloss
# cues; the outermost (_RIM) is where a matte sphere darkens.
_RINGS = ((0.0, 1), (0.22, 6), (0.42, 10), (0.58, 14), (0.72, 18), (0.86, 24))
_MIDDLE = 17  # the first 1 + 6 + 10 samples lie in the middle
_RIM = slice(1 + 6 + 10 + 14 + 18, None)

# The finest difference each learned feature resolves: one level of the 8-bit
# image for the grey-level and LAB features, one of the disk's samples for the
# highlight's area. Standardising divides by the labelled spheres' spread, and
# two grey materials' chroma spreads by 0.02 levels within a frame: a shift of
# one level that lossy video gives later frames then weighed 50 standard
# deviations, and matte POM rising among polished steel was called steel with
# p_heavy = 1 (S-POM-25 in MPEG-4, issue 9). A spread is never taken as finer
# than this resolution.
_N_SAMPLES = sum(n for _, n in _RINGS)
RESOLUTION = {"L": 1.0, "a": 1.0, "b": 1.0, "L_spread": 1.0, "highlight": 1.0,
              "highlight_area": 1.0 / _N_SAMPLES, "rim": 1.0, "texture": 1.0, "specular": 1.0,
              "highlight_at_spots": 1.0}


def sphere_features(image: np.ndarray, centres: np.ndarray, particle_diameter_px: float,
                    spots: np.ndarray | None = None) -> np.ndarray:
    """Appearance of each sphere, (m, len(FEATURES)).

    ``image`` is BGR (or grey) uint8, ``centres`` (m, 2) x, y [px]. Columns:
    median L, a, b of the middle (OpenCV 8-bit LAB); L spread (p90 - p10) of
    the middle; median H, S, V of the middle (H in 0-179); highlight (the
    brightest grey level within 0.86 radii, from a max-filtered copy so that a small
    highlight between samples counts, minus the median); highlight_area (share
    of the disk samples brighter than half-way from median to brightest); rim
    (median grey level at 0.86 radii minus the middle's); texture (mean absolute
    high-pass of the grey image over the middle, grey levels); specular (the
    largest rise of grey above its surroundings at a tenth of a diameter
    within 0.86 radii: a sharp highlight, not a broad reflection);
    highlight_at_spots (the same rise sampled over the disk and weighed by
    ``spots``, the weights :func:`learn_spots` gives; 0 without them).
    """
    if len(centres) == 0:
        return np.zeros((0, len(FEATURES)))
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    d = float(particle_diameter_px)
    smooth = cv2.GaussianBlur(image, (0, 0), max(0.7, d / 40))
    pts = _sample_points(centres, 0.5 * d)
    px, py = pts[..., 0], pts[..., 1]
    # sample first, convert only the samples (converting whole frames cost 50 ms at D = 80 px)
    bgr = cv2.remap(smooth, px[:, :_MIDDLE], py[:, :_MIDDLE], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    lab = _lab8(bgr)
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV).astype(np.float32)
    med = np.median(lab, axis=1)
    spread = np.percentile(lab[..., 0], 90, axis=1) - np.percentile(lab[..., 0], 10, axis=1)
    # the gloss cues on one grey scale; the grey of the blurred colour frame
    # is the blurred grey (both are linear), so no second blur
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32)
    soft = cv2.cvtColor(smooth, cv2.COLOR_BGR2GRAY).astype(np.float32)
    lum = cv2.remap(soft, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    middle = np.median(lum[:, :_MIDDLE], axis=1)
    peak = cv2.dilate(soft, np.ones((3, 3), np.uint8))
    brightest = cv2.remap(peak, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).max(axis=1)
    highlight = np.maximum(brightest - middle, 0.0)
    area = (lum > (middle + 0.5 * highlight)[:, None]).mean(axis=1) * (highlight > 2.0)
    rim = np.median(lum[:, _RIM], axis=1) - middle
    high_pass = np.abs(gray - cv2.GaussianBlur(gray, (0, 0), 1.5))
    texture = cv2.remap(high_pass, px[:, :_MIDDLE], py[:, :_MIDDLE], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).mean(axis=1)
    # a lamp's image on a glossy sphere is small and sharp; the lamps'
    # reflections on the wall and the shading are broad: keep only what
    # stands above its surroundings at a tenth of a diameter
    rises = _sharp_rises(gray, px, py, d)
    specular = rises.max(axis=1)
    at_spots = rises @ spots if spots is not None else np.zeros(len(centres))
    hue = _circular_median_hue(hsv[..., 0])
    sv = np.median(hsv[..., 1:], axis=1)
    return np.column_stack([med, spread, hue, sv, highlight, area, rim, texture, specular, at_spots])


def _sharp_rises(gray: np.ndarray, px: np.ndarray, py: np.ndarray, d: float) -> np.ndarray:
    """How far grey rises above its surroundings at a tenth of a diameter, at the disk's samples
    (m, _N_SAMPLES); a 3 x 3 maximum first, so that a small highlight between samples counts."""
    top_hat = cv2.dilate(gray - cv2.GaussianBlur(gray, (0, 0), max(1.0, d / 10)), np.ones((3, 3), np.uint8))
    return cv2.remap(top_hat, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def disk_rises(image: np.ndarray, centres: np.ndarray, particle_diameter_px: float) -> np.ndarray:
    """Each sphere's sharp rises at the disk's samples (m, _N_SAMPLES): what :func:`spot_weights` weighs."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    pts = _sample_points(np.asarray(centres, dtype=float).reshape(-1, 2), 0.5 * particle_diameter_px)
    return _sharp_rises(image.astype(np.float32), pts[..., 0], pts[..., 1], particle_diameter_px)


def spot_weights(rises: np.ndarray, label: np.ndarray) -> np.ndarray | None:
    """Weights over the disk's samples that read gloss where the glossy kind shows the lamps.

    A lamp's image sits at the same place on every sphere of one kind; a
    speck of dust or a scratch on the wall, anywhere. ``rises``
    (:func:`disk_rises`) and ``label`` (1 heavy, 0 light, -1 unlabelled) of
    the first frame's spheres. The weights are the heavy spheres' mean rise
    minus the light ones', over the two classes' pooled spread plus a grey
    level (so that samples where neither rises weigh nothing), scaled to sum
    to one in absolute value: a sphere's ``highlight_at_spots`` is then in
    grey levels. None if a class is empty or the two do not differ.
    """
    heavy, light = rises[label == 1], rises[label == 0]
    if len(heavy) == 0 or len(light) == 0:
        return None
    spread = np.sqrt(0.5 * (heavy.var(axis=0) + light.var(axis=0)))
    w = (heavy.mean(axis=0) - light.mean(axis=0)) / (spread + 1.0)
    total = np.abs(w).sum()
    return w / total if total > 0 else None


def learn_spots(image: np.ndarray, centres: np.ndarray, particle_diameter_px: float,
                height: np.ndarray, c0: float, n_layers: int) -> np.ndarray | None:
    """:func:`spot_weights` of the first frame's spheres, labelled by where they sit (None if too few)."""
    try:
        label = _labels(np.asarray(height, dtype=float), c0, n_layers)
    except ValueError:
        return None
    return spot_weights(disk_rises(image, centres, particle_diameter_px), label)


def _lab8(bgr: np.ndarray) -> np.ndarray:
    """CIE LAB of uint8 BGR samples on OpenCV's 8-bit scales (L x 255/100, a + 128, b + 128), float32.

    Converted in floating point: OpenCV's 8-bit path took 7.5 ms for 3000
    samples (it builds tables per call), the float path 0.02 ms; they agree
    within about one level.
    """
    lab = cv2.cvtColor(bgr.astype(np.float32) * np.float32(1 / 255), cv2.COLOR_BGR2LAB)
    return lab * np.float32([255 / 100, 1, 1]) + np.float32([0, 128, 128])


def _sample_points(centres: np.ndarray, radius: float) -> np.ndarray:
    offs = [np.zeros((1, 2))]
    for frac, n in _RINGS[1:]:
        t = np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.3 * frac  # rings staggered
        offs.append(frac * radius * np.column_stack([np.cos(t), np.sin(t)]))
    offs = np.concatenate(offs)
    return (centres[:, None, :2] + offs[None]).astype(np.float32)


def _circular_median_hue(h: np.ndarray) -> np.ndarray:
    """Median hue (0-179) that respects the wrap-around at red."""
    ang = h * (2 * np.pi / 180)
    mean = np.arctan2(np.sin(ang).mean(1), np.cos(ang).mean(1))
    dev = (ang - mean[:, None] + np.pi) % (2 * np.pi) - np.pi
    return ((mean + np.median(dev, axis=1)) % (2 * np.pi)) * (180 / (2 * np.pi))


# --------------------------------------------------------------------------- learning


def interface_labels(height: np.ndarray, c0: float, n_layers: int, margin: float = MARGIN) -> np.ndarray:
    """Labels the stratified start gives: 1 heavy, 0 light, -1 too near the interface.

    ``height`` [diameters above the bottom wall] of the first frame's
    spheres; the interface lies at (1 - c0) n_layers diameters (docs/model.md).
    """
    h = np.asarray(height, dtype=float)
    interface = (1.0 - c0) * n_layers
    return np.where(h > interface + margin, 1, np.where(h < interface - margin, 0, -1))


@dataclass(frozen=True)
class Separation:
    """How well, and on what, the two learned classes are told apart.

    cv_accuracy: balanced accuracy of the classifier on the labelled spheres
    under 5-fold cross-validation (1 = perfect, 0.5 = the materials look
    alike). height_share: the share of the score's gap between the classes
    that the height of a sphere explains within its class (0 = the score
    depends on the material only, 1 = on the height only). n_heavy, n_light:
    labelled spheres of each class.
    """

    cv_accuracy: float
    height_share: float
    n_heavy: int
    n_light: int


@dataclass(frozen=True)
class BlurTest:
    """Is there motion blur for the smear-trained classes to undo? (:func:`blur_test`)

    disagree: spheres of the run that the classes learned from sharp spheres
    only and those learned from their smeared copies as well class
    differently; near_plate: how many of them lie within BLUR_ZONE diameters
    of the plate; share_near_plate: the share of all the run's spheres that
    lie there; evidence_against_blur: the Bayes factor of "no blur" (the
    disagreements fall where the spheres are) over "blur" (a share
    BLUR_NEAR_PLATE of them near the plate); smeared: whether the
    smear-trained classes were kept.
    """

    disagree: int
    near_plate: int
    share_near_plate: float
    evidence_against_blur: float
    smeared: bool


# How the features scale with the light a sphere gets. A lamp above the cell
# or at its sides and the lens' vignetting light the view unevenly: a sphere
# lit more looks like the brighter material, and where two materials differ
# in brightness only (a fifth, issue 9) the first frame even learns a fall-off
# of the light down the bed as the material's, the heavy grains sitting
# higher. More light multiplies every grey level of a sphere by one factor s
# (the frame's encoding keeps it a factor), so the gloss cues read in grey
# levels (highlight, rim, sheen) scale by s; OpenCV's LAB decodes the grey
# levels as sRGB, so L + 16 (8-bit: L + 40.8), the spread of L and the colour
# offsets a - 128 and b - 128 scale by s ** (2.2 / 3). One field of s over the
# view, read off the lightness, so that what changes one cue alone (the
# plate's motion blur takes the highlights off the bottom layers' glossy
# spheres) is not taken for light.
_LAB_OFFSET = {0: -40.8, 1: 128.0, 2: 128.0, 3: 0.0}  # L, a, b, L_spread: the value that stays under any light
_GREY = (7, 9, 11)  # highlight, rim, specular: grey levels
_LAB_PER_GREY = 2.2 / 3.0


@dataclass(frozen=True)
class LightField:
    """The light over the view (:func:`light_field`): log(L + 40.8), the lightness' log, as a
    quadratic in a sphere's place, zero at the window's middle; every feature that scales with the
    light is taken back to what it would be there."""

    coef: np.ndarray  # (len(_field_terms),): the field of log(L + 40.8)
    n_layers: int

    def level(self, features: np.ndarray, across: np.ndarray, height: np.ndarray) -> np.ndarray:
        """``features`` as at the window's middle."""
        lab = np.exp(-(_field_terms(across, height, self.n_layers) @ self.coef))  # LAB's factor, undone
        out = np.array(features, dtype=float, copy=True)
        for j, fixed in _LAB_OFFSET.items():
            out[:, j] = fixed + (out[:, j] - fixed) * lab
        out[:, list(_GREY)] *= (lab ** (1.0 / _LAB_PER_GREY))[:, None]
        return out

    def contrast(self) -> float:
        """How many times brighter the view's best-lit place is than its dimmest (grey levels)."""
        return float(np.exp(np.ptp(_over_window(self.coef, self.n_layers)) / _LAB_PER_GREY))


def _field_terms(across: np.ndarray, height: np.ndarray, n_layers: int) -> np.ndarray:
    """The quadratic's terms at each place: ``across`` the window (-1 to 1) and ``height``
    [diameters above the bottom wall], both scaled to -1..1 (vignetting is radial, a lamp above
    falls off down the bed, side lamps across it)."""
    u = np.asarray(across, dtype=float)
    v = 2.0 * np.asarray(height, dtype=float) / n_layers - 1.0
    return np.column_stack([u, v, u * u, v * v, u * v])


def _over_window(coef: np.ndarray, n_layers: int) -> np.ndarray:
    """A field of coefficients ``coef`` (of :func:`_field_terms`) on a grid of places over the window."""
    u, h = np.meshgrid(np.linspace(-1, 1, 21), np.linspace(0, n_layers, 31))
    return _field_terms(u.ravel(), h.ravel(), n_layers) @ coef


def light_field(features: np.ndarray, label: np.ndarray, across: np.ndarray, height: np.ndarray,
                n_layers: int) -> LightField | None:
    """The light over the view read off the labelled spheres: least squares of log(L + 40.8) on the
    class (``label`` 1 / 0) and the field's terms. The class takes the step at the interface, the
    field what changes smoothly within each class; a step and a quadratic cannot trade, so a lamp
    above is told from the material even though the first frame holds each class at one end. But
    the terms up the bed (which the step partly mimics) are known far less well than those across
    it, and a term read wrong moves every sphere taken to the other end of the bed, as the
    un-mixing does: the weakest term is dropped while it is under FIELD_T standard errors. None
    where no term is left."""
    terms = _field_terms(across, height, n_layers)
    lightness = np.log(np.maximum(np.asarray(features, dtype=float)[:, 0] - _LAB_OFFSET[0], 1.0))
    keep = list(range(terms.shape[1]))
    while keep:
        design = np.column_stack([np.ones(len(label)), label, terms[:, keep]])
        coef, *_ = np.linalg.lstsq(design, lightness, rcond=None)
        dof = max(len(label) - design.shape[1], 1)
        scatter = float(np.sum((lightness - design @ coef) ** 2)) / dof
        error = np.sqrt(np.maximum(np.diag(np.linalg.pinv(design.T @ design))[2:] * scatter, 1e-300))
        weakest = int(np.argmin(np.abs(coef[2:]) / error))
        if abs(coef[2 + weakest]) >= FIELD_T * error[weakest]:
            full = np.zeros(terms.shape[1])
            full[keep] = coef[2:]
            return LightField(full, n_layers)
        keep.pop(weakest)
    return None


# A term of the light's field is kept where it stands three standard errors
# clear of zero (lit level, the terms up the bed came out at 0.0-0.9 of their
# error on the brightness-only pair's tuning seeds; under a lamp above, 5).
FIELD_T = 3.0


@dataclass(frozen=True)
class MaterialClasses:
    """The learned heavy / light classifier and how well it separates the labelled spheres.

    blur: the test that chose between the classes learned with and without
    smeared copies (None where only one was learned).
    """

    model: object  # a fitted scikit-learn pipeline
    separation: Separation
    blur: BlurTest | None = None
    columns: tuple[int, ...] = LEARNED  # the FEATURES the model reads: LEARNED or LEARNED_AT_SPOTS
    uses_height: bool = False  # the model also reads each sphere's height (offered when learned from both ends)
    both_ends: bool = False  # learned from the first frame and the un-mixed last (learn_classes' labelled_by)
    field: LightField | None = None  # the light over the view, taken off the features before the model reads them
    light_share: float | None = None  # how far that light moved the score, as a share of the class gap (None: not read)

    def p_heavy(self, features: np.ndarray, height: np.ndarray | None = None,
                across: np.ndarray | None = None) -> np.ndarray:
        """Probability [0, 1] that each sphere (features (m, len(FEATURES))) is heavy; ``height``
        [diameters above the bottom wall] is needed by classes learned from both ends of a run or
        with a light field, ``across`` (the window's width from -1 to 1) by the latter."""
        if len(features) == 0:
            return np.zeros(0)
        if (self.uses_height or self.field is not None) and height is None:
            raise ValueError("these classes read the spheres' heights (learned from both ends of a run, or with "
                             "the light over the view taken off)")
        if self.field is not None:
            if across is None:
                raise ValueError("these classes take the light over the view off and need where the spheres lie "
                                 "across the window")
            features = self.field.level(features, across, height)
        return self.model.predict_proba(_model_input(features, height if self.uses_height else None,
                                                     self.columns))[:, 1]

    @property
    def gloss_at_spots(self) -> bool:
        """Whether gloss is read at the learned spots (else as the disk's brightest points)."""
        return self.columns[:len(LEARNED_AT_SPOTS)] == LEARNED_AT_SPOTS


# Horizontal smears [diameters] the labelled spheres are also learned under.
# The plate moves ~0.17 m/s: at 1/60 s a sphere next to it smears by half a
# diameter, while the first frame's heavy spheres, all high up, are sharp. A
# classifier that has only seen sharp heavy spheres calls blurred ones light
# (polished steel reaching the bottom layers of an S-POM run: its highlights
# smear into the body; issue 9). Showing it the labelled spheres smeared as
# the fast layers are makes the classes hold wherever a sphere is.
SMEARS = (0.15, 0.3, 0.5)
# But the smeared copies cost where nothing is blurred: a glossy sphere
# smeared loses its highlight, so the classes learned with them lean on
# weaker cues (glossy over matte grey in the physically based footage: 96 %
# right instead of 100 %). Motion blur acts only next to the moving plate
# (the shear band, about 0.18 H = 2.7 diameters deep), so where it is real
# the two sets of classes disagree there and hardly anywhere else.
# :func:`blur_test` drops the smear-trained classes only when where the two
# disagree is decisive evidence (Bayes factor > BLUR_EVIDENCE, "decisive" on
# Jeffreys' scale) that they do not crowd near the plate; with few
# disagreements the smear-trained classes stay, as they always did.
BLUR_ZONE = 3.0
BLUR_NEAR_PLATE = 0.8  # least share of disagreements near the plate on the blurred 2-D looks, seeds 7-8
BLUR_EVIDENCE = 100.0


def smeared_images(image: np.ndarray, particle_diameter_px: float,
                   smears: tuple[float, ...] = SMEARS) -> list[np.ndarray]:
    """``image`` box-blurred along x by each of ``smears`` [diameters], as the moving plate smears."""
    out = []
    for smear in smears:
        k = max(1, int(round(smear * particle_diameter_px)))
        kernel = np.full((1, k), 1.0 / k, np.float32)
        out.append(cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REPLICATE))
    return out


def blur_test(height: np.ndarray, sharp_heavy: np.ndarray, smeared_heavy: np.ndarray) -> BlurTest:
    """Keep the smear-trained classes? Not if where they disagree with the sharp ones is far from the plate.

    ``height`` [diameters above the bottom wall] of every sphere of the run,
    ``sharp_heavy`` / ``smeared_heavy`` (bool) its class by the classes
    learned without / with smeared copies. With motion blur the two disagree
    on the smeared spheres of the fast bottom layers; without it, on a few
    spheres anywhere. Measured (2-D renderer seeds 7-8, physically based
    tuning packings): blurred looks put 80-100 % of their 5-15 disagreements
    within 3 diameters of the plate; unblurred ones 6-30 % of 6-27, about
    the 19 % of the spheres that lie there.
    """
    h = np.asarray(height, dtype=float)
    differ = np.asarray(sharp_heavy, dtype=bool) != np.asarray(smeared_heavy, dtype=bool)
    near = h < BLUR_ZONE
    share = float(np.clip(near.mean(), 1e-3, 1 - 1e-3)) if len(h) else 0.5
    k, n = int((differ & near).sum()), int(differ.sum())
    # likelihood of k of the n near the plate if they fall like the spheres, over if they crowd there
    log_bf = k * np.log(share / BLUR_NEAR_PLATE) + (n - k) * np.log((1 - share) / (1 - BLUR_NEAR_PLATE))
    evidence = float(np.exp(min(log_bf, 700.0)))
    return BlurTest(n, k, share, evidence, not evidence > BLUR_EVIDENCE)


def learn_classes(features: np.ndarray, height: np.ndarray, c0: float, n_layers: int,
                  augmented: list[np.ndarray] | tuple = (), seed: int = 0,
                  rises: list[np.ndarray] | None = None,
                  labelled_by: np.ndarray | None = None,
                  across: np.ndarray | None = None, light_of: MaterialClasses | None = None) -> MaterialClasses:
    """Learn heavy and light from the first frame's spheres (and the last frame's, ``labelled_by``).

    ``features`` (m, len(FEATURES)) and ``height`` [diameters above the bottom
    wall] of the first frame's spheres; ``c0`` the heavy volume fraction;
    ``augmented``: the same spheres' features under other imaging conditions
    (e.g. :func:`sphere_features` of :func:`smeared_images`), learned from as well. Raises ValueError
    if fewer than MIN_PER_CLASS spheres of either class lie clear of the
    interface.

    Gloss is read either as the disk's brightest points (:data:`LEARNED`) or
    at the learned spots (:data:`LEARNED_AT_SPOTS`). The spots are tried only
    with ``rises``, the spheres' :func:`disk_rises` for ``features`` and each
    of ``augmented``: the spot weights are fitted to the labels, so each
    cross-validation fold fits its own from its training spheres (weights
    that had seen the held-out labels made two identical materials look 71 %
    separable instead of 52 %). The classes kept are those with the lower
    cross-validated log-loss; a speck of dust over a labelled sphere shows up
    there as a confident miss. The final classes read the ``features`` as
    given (their spot column from weights fitted to every labelled sphere,
    as every frame's is).

    ``labelled_by``: the heights [diameters] that label the spheres, where
    they differ from ``height``: a run whose density ratio leaves it un-mixed
    at the end shows heavy below c0 H and light above, the first frame turned
    upside down, so its last frame's spheres come labelled by n_layers less
    their height. With them, every class is seen high and low, so a look
    that changes with height (a lamp above the cell, the plate's motion blur)
    can no longer pass for the material, and each sphere's height is
    offered as one more input to take such a change off, kept where it
    lowers the cross-validated log-loss (``uses_height``).

    ``across`` (each sphere's place across the window, -1 to 1): the light
    over the view is read and, where it moves the classes by much, taken off
    (:func:`light_field`, LIGHT_SHARE), unless both ends label the spheres. ``light_of``: classes learned from the
    same spheres whose light (taken off or not) is used instead of reading it
    again, so that classes learned with and without smeared copies differ in
    nothing else.
    """
    h = np.asarray(height, dtype=float)
    both_ends = labelled_by is not None
    label = _labels(np.asarray(labelled_by, dtype=float) if both_ends else h, c0, n_layers)
    use = label >= 0
    y, h = label[use], h[use]
    n_heavy, n_light = int((y == 1).sum()), int((y == 0).sum())
    raw = [np.asarray(v, dtype=float)[use] for v in (features, *augmented)]
    rises = None if rises is None else [np.asarray(r, dtype=float)[use] for r in rises]
    at = h if both_ends else None
    columns, model, accuracy, score = _learned(raw, y, at, seed, rises)
    field, share = None, None
    if across is not None:  # where the light over the view moves the score by much, it is taken off
        a = np.asarray(across, dtype=float)[use]
        if light_of is not None:
            field, share = light_of.field, light_of.light_share
        else:
            share = _light_share(score, y, a, h, n_layers)
            # classes learned from both ends see each class high and low, with its height offered:
            # taking the light off as well cost there (BENCHMARKS.md)
            taken = LEVEL_LIGHT and not both_ends and share >= LIGHT_SHARE
            field = light_field(raw[0], y, a, h, n_layers) if taken else None
        if field is not None:
            columns, model, accuracy, score = _learned([field.level(v, a, h) for v in raw], y, at, seed, rises)
    return MaterialClasses(model, Separation(accuracy, _height_share(score, y, h), n_heavy, n_light), columns=columns,
                           uses_height=HEIGHT_COLUMN in columns, both_ends=both_ends, field=field, light_share=share)


def _learned(raw: list[np.ndarray], y: np.ndarray, height: np.ndarray | None, seed: int,
             rises: list[np.ndarray] | None) -> tuple[tuple[int, ...], object, float, np.ndarray]:
    """The classes of the labelled spheres' features (``raw``, one array per view), ``y`` their labels:
    the columns kept, the model, its cross-validated balanced accuracy and its score on the first view.
    With ``height`` (both ends label the spheres) each sphere's height is offered as an input; with
    ``rises``, gloss at the learned spots; each kept where it lowers the cross-validated log-loss."""
    views = [_with_height(v, height) for v in raw]
    sets = [LEARNED] + ([LEARNED + (HEIGHT_COLUMN,)] if height is not None else [])
    tried = [(cols, *_fit_classes(views, y, cols, seed)) for cols in sets]
    if rises is not None:
        tried += [(LEARNED_AT_SPOTS + cols[len(LEARNED):], *_fit_classes(views, y, LEARNED_AT_SPOTS + cols[len(LEARNED):],
                                                                          seed, rises)) for cols in sets]
    columns, model, _, accuracy = min(tried, key=lambda t: t[2])  # the lower log-loss
    return columns, model, accuracy, model.decision_function(views[0][:, columns])


def _light_share(score: np.ndarray, label: np.ndarray, across: np.ndarray, height: np.ndarray,
                 n_layers: int) -> float:
    """How far the light over the view moves the classes' ``score`` over the window, as a share of
    the gap between the classes: least squares of the score on the class and the field's terms
    (:func:`light_field`), the field's range against the class's coefficient (inf where the
    classes' scores do not differ)."""
    design = np.column_stack([np.ones(len(label)), label, _field_terms(across, height, n_layers)])
    coef, *_ = np.linalg.lstsq(design, score, rcond=None)
    gap = abs(coef[1])
    return float(np.ptp(_over_window(coef[2:], n_layers)) / gap) if gap > 1e-9 else float("inf")


# The light over the view is taken off the features where, before, it moved
# the classes' score over the window by this share of the gap between the
# classes or more: then a sphere at the view's dim end and one at its bright
# end differ by half the way to the other class. Below it the classes hold
# wherever a sphere lies, and learning them again would only move where their
# boundary falls among spheres that look like neither (polished steel resting
# on the plate, mirroring it: S-POM-25 at seed 9 put one in the wrong class).
# Measured on the 2-D renderer, tuning seeds 7-8: 0.08-0.15 where the
# materials differ in more than brightness, 0.51-0.60 for the brightness-only
# pair lit level and 0.68-1.02 under a lamp above (BENCHMARKS.md).
LIGHT_SHARE = 0.25
LEVEL_LIGHT = True  # False: the light is never taken off (what the benchmarks compare against)


# Where a sphere's height [diameters] sits among the model's inputs when the
# classes read it: one column past FEATURES. It needs no finer resolution
# than a tenth of a diameter.
HEIGHT_COLUMN = len(FEATURES)
_HEIGHT_RESOLUTION = 0.1


def _with_height(features: np.ndarray, height: np.ndarray | None) -> np.ndarray:
    """``features`` with each sphere's height as one more column (unchanged without heights)."""
    return features if height is None else np.column_stack([features, height])


def _model_input(features: np.ndarray, height: np.ndarray | None, columns: tuple[int, ...]) -> np.ndarray:
    """The model's columns of ``features`` (with ``height`` as HEIGHT_COLUMN, if given)."""
    return _with_height(np.asarray(features, dtype=float), height)[:, columns]


def _labels(height: np.ndarray, c0: float, n_layers: int) -> np.ndarray:
    """:func:`interface_labels` with the widest of MARGINS that leaves MIN_PER_CLASS spheres a class."""
    for margin in MARGINS:
        label = interface_labels(height, c0, n_layers, margin)
        n_heavy, n_light = int((label == 1).sum()), int((label == 0).sum())
        if min(n_heavy, n_light) >= MIN_PER_CLASS:
            return label
    raise ValueError(
        f"the first frame shows {n_heavy} spheres above and {n_light} below the initial interface "
        f"at (1 - c0) H = {(1 - c0) * n_layers:.1f} diameters; need {MIN_PER_CLASS} of each to "
        f"learn heavy from light (is c0 right? does the recording start stratified?)")


_SPOT_COLUMN = FEATURES.index("highlight_at_spots")


def _fit_classes(views: list[np.ndarray], y: np.ndarray, columns: tuple[int, ...], seed: int,
                 rises: list[np.ndarray] | None = None) -> tuple[object, float, float]:
    """A classifier on ``columns`` of the labelled spheres' ``views`` (labels ``y``), its 5-fold
    cross-validated log-loss [nats a sphere] and balanced accuracy. With ``rises`` (one per view),
    each fold reads the spot column with weights fitted to its own training spheres."""

    def fit(rows: np.ndarray, vs: list[np.ndarray]):
        # Logistic regression: outliers (a shadowed sphere, a highlight off
        # centre) pull a linear boundary less than they pull a Gaussian class,
        # and its probabilities are usable as they come.
        model = make_pipeline(ResolvedScaler([_HEIGHT_RESOLUTION if j == HEIGHT_COLUMN else RESOLUTION[FEATURES[j]]
                                              for j in columns]),
                              LogisticRegression(C=1.0, max_iter=1000))
        return model.fit(np.concatenate([v[rows][:, columns] for v in vs]), np.tile(y[rows], len(vs)))

    def fold_views(train: np.ndarray) -> list[np.ndarray]:
        if rises is None:
            return views
        w = spot_weights(rises[0][train], y[train])
        out = []
        for v, r in zip(views, rises, strict=True):
            v = v.copy()
            v[:, _SPOT_COLUMN] = r @ w if w is not None else 0.0
            out.append(v)
        return out

    # cross-validated by sphere: a sphere's smeared copies stay in its fold
    n_splits = min(5, int((y == 1).sum()), int((y == 0).sum()))
    folds = StratifiedKFold(n_splits=n_splits, shuffle=True, random_state=seed)
    p = np.empty(len(y))
    for train, test in folds.split(views[0], y):
        vs = fold_views(train)
        p[test] = fit(train, vs).predict_proba(vs[0][test][:, columns])[:, 1]
    p = np.clip(p, 1e-12, 1 - 1e-12)
    loss = float(-np.mean(np.where(y == 1, np.log(p), np.log1p(-p))))
    predicted = p > 0.5
    accuracy = 0.5 * (predicted[y == 1].mean() + (~predicted[y == 0]).mean())
    return fit(np.arange(len(y)), views), loss, float(accuracy)


class ResolvedScaler(StandardScaler):
    """Standardises features, but never by a spread finer than each feature can be measured to
    (``resolution``, one value per column): a feature constant to within a grey level among the
    labelled spheres must not weigh a one-level change as many standard deviations."""

    def __init__(self, resolution=None, *, copy=True, with_mean=True, with_std=True):
        super().__init__(copy=copy, with_mean=with_mean, with_std=with_std)
        self.resolution = resolution

    def fit(self, X, y=None, sample_weight=None):
        super().fit(X, y, sample_weight)
        if self.resolution is not None and self.with_std:
            self.scale_ = np.maximum(self.scale_, np.asarray(self.resolution, dtype=float))
        return self


def _height_share(score: np.ndarray, label: np.ndarray, height: np.ndarray) -> float:
    """Share of the between-class score gap that height explains within the classes.

    Least squares score ~ a + b label + s height: s (height - its class mean
    difference) against the whole gap. Near 0 for a material cue; near 1 when
    the score is a function of height (light falling off down the frame, the
    blur of the moving bottom layers) and the classes only differ in where
    they sit.
    """
    gap = score[label == 1].mean() - score[label == 0].mean()
    dh = height[label == 1].mean() - height[label == 0].mean()
    a = np.column_stack([np.ones_like(height), label, height])
    coef, *_ = np.linalg.lstsq(a, score, rcond=None)
    if not np.isfinite(gap) or abs(gap) < 1e-9:
        return 1.0
    return float(np.clip(coef[2] * dh / gap, 0.0, 1.0))


def classify_by_ranges(features: np.ndarray, ranges: dict[str, np.ndarray]) -> np.ndarray:
    """Heavy by explicit colour ranges (``heavy_hsv``, ``light_hsv``, ``heavy_lab``, ``light_lab``).

    A sphere is heavy if its median colour lies in a heavy range, or if only
    light ranges are given and it lies in none of them.
    """
    cols = {"lab": features[:, 0:3], "hsv": features[:, 4:7]}

    def inside(key: str) -> np.ndarray:
        lo, hi = ranges[key]
        v = cols[key.split("_")[1]]
        return np.all((v >= lo) & (v <= hi), axis=1)

    heavy_keys = [k for k in ranges if k.startswith("heavy_")]
    light_keys = [k for k in ranges if k.startswith("light_")]
    if heavy_keys:
        return np.any([inside(k) for k in heavy_keys], axis=0)
    return ~np.any([inside(k) for k in light_keys], axis=0)
