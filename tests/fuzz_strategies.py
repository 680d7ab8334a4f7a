"""Hypothesis strategies for the fuzz suite (issue 14, "nothing aborts, hangs or hides").

Each strategy draws a *recipe*: plain data (a fault kind, the field or option it targets, the
values) that :mod:`test_fuzz` turns into files, folders or calls in a fresh scratch folder, so a
failing example prints as something one can read and replay. Every fault kind a strategy can
produce is registered in :data:`FAULTS` under its entry point (``fault(entry, kind, about)``);
the strategies draw kinds *from the registry*, so a kind that is registered is tried, and one that
is tried is counted. The command-line kinds are derived from ``granseg.cli.build_parser()``: a new
subcommand or option is fuzzed (and counted) without editing this file.

    python tests/fuzz_strategies.py --count     # markdown table of fault kinds per entry point

Known open bugs (issue 14, being fixed in the CLI and validation code elsewhere) are listed in
:data:`KNOWN`; a recipe that would hit one carries its tag in ``Recipe.known`` and the tests
accept the failure for that recipe only (strict: the tag must match what happened).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

# --------------------------------------------------------------------------- the registry

#: entry point -> fault kind -> what the kind does. Filled by :func:`fault` at import.
FAULTS: dict[str, dict[str, str]] = {}


def fault(entry: str, kind: str, about: str) -> str:
    """Register fault ``kind`` of entry point ``entry``; return the kind."""
    FAULTS.setdefault(entry, {})[kind] = about
    return kind


def kinds(entry: str) -> list[str]:
    """Every registered kind of ``entry``, in registration order."""
    return list(FAULTS[entry])


#: Open bugs a recipe may hit, tag -> what: a failure tagged with one of these is counted, not raised.
#: Empty: the twelve issue-14 bugs the suite was written against (huge integers in experiment.json,
#: particle_diameter_px 5000, grey frames, --workers 0, --preview-count -2, --set D_p=1, report
#: --c0 5, a first frame of another size, t0 < 0, non-UTF-8 names, diagnose on 14 layers, late
#: output clashes) are fixed, so the recipes that carry their tags must now pass. Add a tag here
#: only for a bug found and not yet fixed, with the issue that tracks it.
KNOWN: dict[str, str] = {}


@dataclass(frozen=True)
class Recipe:
    """One fuzz case: which entry point, which fault kind, and what to build."""

    entry: str
    kind: str
    target: str = ""  #: the field, key or option the fault is in ("" = the whole input)
    args: dict[str, Any] = field(default_factory=dict)
    #: names one of which the error message must contain (beyond the file/dir it is about)
    names: tuple[str, ...] = ()
    known: str | None = None  #: a KNOWN tag when this recipe may hit that open bug


# --------------------------------------------------------------------------- shared values

#: Numbers a JSON or Python caller may pass where a positive finite float is expected.
BAD_NUMBERS: dict[str, Any] = {
    "zero": 0,
    "negative": -2,
    "nan": float("nan"),
    "inf": float("inf"),
    "-inf": float("-inf"),
    "huge-int": 10**400,  # JSON allows it; float() of it is an OverflowError
    "huge-float": 1e300,
    "tiny": 1e-300,
    "string-number": "2.5",
    "string": "abc",
    "empty-string": "",
    "bool": True,
    "null": None,
    "list": [1, 2],
    "dict": {"a": 1},
}

#: The same edge cases as command-line text.
BAD_ARG_NUMBERS: dict[str, str] = {
    "zero": "0", "negative": "-2", "nan": "nan", "inf": "inf", "-inf": "-inf", "overflow": "1e400",
    "empty": "", "huge-int": "99999999999999999999999", "tiny": "1e-300", "word": "abc", "fraction": "2.5",
}


def small_floats(lo: float = 0.0, hi: float = 1.0) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


# --------------------------------------------------------------------------- (a) map files

D_P = 0.006
TEXT_KEYS = ("name", "heavy", "light")
SCALAR_KEYS = ("rho_h", "rho_l", "c0", "M_g", "M_w")
ARRAY_KEYS = ("c", "t", "z")
MAP_KEYS = (*ARRAY_KEYS, *TEXT_KEYS, *SCALAR_KEYS)
OPTIONAL_KEYS = ("n", "n_heavy", "c_raw", "fps", "smoothing_frames", "quality", "view")
CELL_KEYS = ("H", "D_p", "D_in", "D_out", "rpm", "v1", "phi_s", "g")

MAP = "load_map"
for _k, _about in [
    ("valid", "an untouched valid map (must load)"),
    ("truncated", "the file cut at a random byte"),
    ("flipped-bytes", "1-8 random bytes xor-ed"),
    ("missing-key", "a required key left out"),
    ("wrong-dtype", "a key stored as text, bool, complex or a structured array"),
    ("wrong-shape", "a key of the wrong number of dimensions or length, or empty"),
    ("bad-values", "NaN, inf, negative or > 1 entries in c, t, z or the scalars"),
    ("non-monotone-t", "t (or z) not strictly increasing"),
    ("huge-header", "a .npy header claiming an enormous shape"),
    ("object-array", "a pickled object array (the pickle must never run)"),
    ("bad-text", "empty, non-UTF-8 bytes, or an array where a text field is"),
    ("bad-optional", "counts negative or n_heavy > n, even smoothing width, junk quality, unknown view"),
    ("bad-cell", "cell keys out of range (H <= 0, D_out <= D_in, phi_s > 1, ...)"),
    ("junk-members", "members that are not .npy, directories, nested archives, a duplicated member"),
    ("not-a-zip", "random bytes, an empty file, a gzip or a plain .npy"),
]:
    fault(MAP, _k, _about)


def valid_map_arrays(n_t: int = 6, n_layers: int = 15, seed: int = 0, name: str = "G-PP-50",
                     cell: dict[str, float] | None = None) -> dict[str, Any]:
    """A valid map's arrays as a file holds them (strings as np.str_)."""
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = dict(
        c=rng.uniform(0, 1, (n_t, n_layers)), t=np.arange(n_t) * 60.0, z=(np.arange(n_layers) + 0.5) * D_P,
        name=np.str_(name), heavy=np.str_("glass"), light=np.str_("PP"), rho_h=np.float64(2450.0),
        rho_l=np.float64(946.0), c0=np.float64(0.5), M_g=np.float64(2.04), M_w=np.float64(1.093),
    )
    for k, v in (cell or {}).items():
        out[k] = np.float64(v)
    return out


def npz_bytes(arrays: dict[str, Any], compressed: bool = False) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def npy_bytes(header: dict[str, Any], data: bytes) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + data


class PickleBomb:
    """Unpickling it makes the folder ``marker``: proof that a reader executed a pickle."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


@st.composite
def map_recipes(draw: Callable, kind: str | None = None) -> Recipe:
    """A recipe for one (usually damaged) map .npz; build it with :func:`build_map`."""
    kind = kind or draw(st.sampled_from(kinds(MAP)))
    n_t = draw(st.integers(2, 8))
    n_layers = draw(st.sampled_from([15, 15, 4, 1]))
    a: dict[str, Any] = {"n_t": n_t, "n_layers": n_layers, "seed": draw(st.integers(0, 3)),
                         "compressed": draw(st.booleans())}
    target, names = "", ()
    if kind == "truncated":
        a["keep"] = draw(st.floats(0.0, 0.999))
    elif kind == "flipped-bytes":
        a["flips"] = draw(st.lists(st.tuples(st.floats(0.0, 0.999), st.integers(1, 255)), min_size=1, max_size=8))
    elif kind == "missing-key":
        target = draw(st.sampled_from(MAP_KEYS))
    elif kind == "wrong-dtype":
        target = draw(st.sampled_from(MAP_KEYS + ("n", "fps", "smoothing_frames", "H")))
        a["as"] = draw(st.sampled_from(["text", "bool", "complex", "structured", "datetime"]))
    elif kind == "wrong-shape":
        target = draw(st.sampled_from(ARRAY_KEYS + SCALAR_KEYS + ("n", "c_raw", "fps")))
        a["shape"] = draw(st.sampled_from(["0d", "1d", "3d", "longer", "shorter", "empty"]))
    elif kind == "bad-values":
        target = draw(st.sampled_from(ARRAY_KEYS + SCALAR_KEYS + ("c_raw", "fps") + CELL_KEYS))
        a["value"] = draw(st.sampled_from([np.nan, np.inf, -np.inf, -1.0, 1.5, 0.0, 1e308, -0.0]))
        a["everywhere"] = draw(st.booleans())
    elif kind == "non-monotone-t":
        target = draw(st.sampled_from(["t", "z"]))
        a["how"] = draw(st.sampled_from(["repeat", "reverse", "swap"]))
    elif kind == "huge-header":
        target = draw(st.sampled_from(ARRAY_KEYS + ("rho_h", "n")))
        a["shape"] = draw(st.sampled_from([(10**9, 15), (2**62,), (2**31, 2**31), (-1, 15), (10**30,)]))
        a["descr"] = draw(st.sampled_from(["<f8", "<U1000000", "|V100000000", "<f8"]))
    elif kind == "object-array":
        target = draw(st.sampled_from(MAP_KEYS + ("quality", "junk")))
    elif kind == "bad-text":
        target = draw(st.sampled_from(TEXT_KEYS + ("quality", "view")))
        a["text"] = draw(st.sampled_from(["empty", "spaces", "non-utf8", "array", "huge"]))
    elif kind == "bad-optional":
        target = draw(st.sampled_from(["n", "n_heavy", "smoothing_frames", "quality", "view", "c_raw"]))
        a["variant"] = draw(st.integers(0, 3))
    elif kind == "bad-cell":
        target = draw(st.sampled_from(CELL_KEYS))
        a["value"] = draw(st.sampled_from([0.0, -1.0, np.nan, np.inf, 2.0, 1e-300]))
    elif kind == "junk-members":
        a["junk"] = draw(st.sampled_from(["not-npy", "directory", "nested-zip", "duplicate", "empty-member",
                                          "npy-bad-magic", "npy-v3"]))
    elif kind == "not-a-zip":
        a["what"] = draw(st.sampled_from(["random", "empty", "gzip", "npy", "zip-empty", "text"]))
        a["random"] = draw(st.binary(min_size=0, max_size=64))
    if target:
        names = (f"'{target}'",)
    return Recipe(MAP, kind, target, a, names)


def _mutated_arrays(r: Recipe, marker: str) -> dict[str, Any]:
    """The arrays of a map recipe after its key-level mutation."""
    a = r.args
    arrays = valid_map_arrays(a["n_t"], a["n_layers"], a["seed"])
    k = r.target
    shape = arrays["c"].shape
    if r.kind == "missing-key":
        del arrays[k]
    elif r.kind == "wrong-dtype":
        arrays[k] = {"text": np.str_("0.5"), "bool": np.ones(shape, bool) if k in ("c", "n") else np.bool_(True),
                     "complex": np.ones(np.shape(arrays.get(k, 1.0)), complex),
                     "structured": np.zeros(np.shape(arrays.get(k, 1.0)), dtype=[("a", "<f8"), ("b", "<i4")]),
                     "datetime": np.zeros(np.shape(arrays.get(k, 1.0)), dtype="datetime64[s]")}[a["as"]]
    elif r.kind == "wrong-shape":
        v = np.asarray(arrays.get(k, np.ones(shape)))
        arrays[k] = {"0d": np.float64(0.5), "1d": np.full(3, 0.5), "3d": np.full((2, 2, 2), 0.5),
                     "longer": np.concatenate([v.ravel(), v.ravel()[-1:] + 1]),
                     "shorter": v.ravel()[:-1], "empty": np.zeros((0,) * max(v.ndim, 1))}[a["shape"]]
        if k in ("n",):
            arrays[k] = arrays[k].astype(np.int64)
    elif r.kind == "bad-values":
        if k in CELL_KEYS or k == "fps":
            arrays[k] = np.float64(a["value"])
        else:
            v = np.array(arrays.get(k, arrays["c"]), dtype=float)
            if v.ndim == 0 or a["everywhere"]:
                v = np.full(v.shape, a["value"])
            else:
                v.flat[v.size // 2] = a["value"]
            arrays[k] = v
    elif r.kind == "non-monotone-t":
        v = arrays[k].copy()
        if a["how"] == "repeat":
            v[-1] = v[-2] if v.size > 1 else v[-1]
        elif a["how"] == "reverse":
            v = v[::-1].copy()
        else:
            v[[0, -1]] = v[[-1, 0]]
        arrays[k] = v
    elif r.kind == "object-array":
        arrays[k] = np.array([PickleBomb(marker), 1.0], dtype=object)
    elif r.kind == "bad-text":
        arrays[k] = {"empty": np.str_(""), "spaces": np.str_("   "), "non-utf8": np.bytes_(b"G-\xff\xfe"),
                     "array": np.array(["a", "b"]), "huge": np.str_("x" * 100_000)}[a["text"]]
    elif r.kind == "bad-optional":
        n = np.full(shape, 10, dtype=np.int64)
        v = a["variant"]
        if k == "n":
            arrays["n"] = [-n, n.astype(float), n[:1], np.full(shape, 2**63 - 1, dtype=np.int64)][v]
        elif k == "n_heavy":
            arrays["n"], arrays["n_heavy"] = n, [n + 1, -n, n.astype(np.uint8) * 30, n[:, :1]][v]
        elif k == "smoothing_frames":
            arrays[k] = [np.int64(4), np.int64(-3), np.float64(2.5), np.int64(2**62)][v]
        elif k == "quality":
            arrays[k] = np.str_(['{"ok": "yes"}', "[1, 2]", "{not json", '{"ok": false, "checks": 5}'][v])
        elif k == "view":
            arrays[k] = np.str_(["side", "", "WALL", "bulk\x00"][v])
        else:
            arrays[k] = [np.full(shape, 2.0), np.full(shape, -0.1), np.full((1, 1), 0.5), np.full(shape, np.inf)][v]
    elif r.kind == "bad-cell":
        arrays[k] = np.float64(a["value"])
        if k == "D_out":
            arrays["D_in"] = np.float64(1.0)
    return arrays


def build_map(r: Recipe, path: Path, marker: str) -> None:
    """Write the (damaged) map file of recipe ``r`` at ``path``; ``marker`` is the folder a
    pickle in it would create if it ever ran."""
    a = r.args
    if r.kind == "not-a-zip":
        what = a["what"]
        if what == "random":
            data = a["random"]
        elif what == "empty":
            data = b""
        elif what == "gzip":
            import gzip
            data = gzip.compress(b"not a map")
        elif what == "npy":
            buf = io.BytesIO()
            np.save(buf, np.ones(3))
            data = buf.getvalue()
        elif what == "zip-empty":
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w"):
                pass
            data = buf.getvalue()
        else:
            data = b"c,t\n0.5,0\n"
        path.write_bytes(data)
        return
    arrays = _mutated_arrays(r, marker)
    if r.kind == "huge-header":
        header = {"descr": a["descr"], "fortran_order": False, "shape": tuple(a["shape"])}
        with zipfile.ZipFile(path, "w") as zf:
            for key, value in arrays.items():
                if key == r.target:
                    try:
                        zf.writestr(f"{key}.npy", npy_bytes(header, bytes(64)))
                    except ValueError:  # numpy refuses to even write a negative shape: forge it
                        text = repr(header).encode() + b" " * 10 + b"\n"
                        zf.writestr(f"{key}.npy", b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text)
                else:
                    buf = io.BytesIO()
                    np.save(buf, value)
                    zf.writestr(f"{key}.npy", buf.getvalue())
        return
    if r.kind == "junk-members":
        data = npz_bytes(arrays, a["compressed"])
        with zipfile.ZipFile(path, "w") as zf:
            with zipfile.ZipFile(io.BytesIO(data)) as src:
                for info in src.infolist():
                    zf.writestr(info.filename, src.read(info))
            junk = a["junk"]
            if junk == "not-npy":
                zf.writestr("readme.txt", "hello")
            elif junk == "directory":
                zf.writestr(zipfile.ZipInfo("sub/"), "")
            elif junk == "nested-zip":
                zf.writestr("inner.npz", data)
            elif junk == "duplicate":
                import warnings
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    buf = io.BytesIO()
                    np.save(buf, np.full(arrays["c"].shape, 7.0))
                    zf.writestr("c.npy", buf.getvalue())
            elif junk == "empty-member":
                zf.writestr("extra.npy", b"")
            elif junk == "npy-bad-magic":
                zf.writestr("extra.npy", b"\x93NUMPY\x09\x09garbage")
            else:
                text = b"{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }"
                text += b" " * (64 - (12 + len(text)) % 64 - 1) + b"\n"
                zf.writestr("extra.npy", b"\x93NUMPY\x03\x00" + len(text).to_bytes(4, "little") + text + bytes(24))
        return
    data = npz_bytes(arrays, a["compressed"])
    if r.kind == "truncated":
        data = data[: int(len(data) * a["keep"])]
    elif r.kind == "flipped-bytes":
        b = bytearray(data)
        for where, mask in a["flips"]:
            b[int(where * len(b))] ^= mask
        data = bytes(b)
    path.write_bytes(data)


# --------------------------------------------------------------------------- (b) campaign folders

CAMPAIGN = "load_campaign"
ENTRY_KINDS = {
    "valid-map": "a valid map",
    "broken-map": "a damaged map (any kind of load_map's)",
    "hidden-file": "a hidden file (.DS_Store, a stale .NAME.npz.x.npz or .partial)",
    "symlink-valid": "a symbolic link to a valid map",
    "symlink-dangling": "a symbolic link to nothing",
    "symlink-loop": "a symbolic link to itself",
    "symlink-dir": "a .npz symbolic link to a folder",
    "non-utf8-name": "a valid map under a name that is not UTF-8",
    "subfolder": "a sub-folder (with a map inside, not to be read)",
    "dir-named-npz": "an empty folder named like a map",
    "other-file": "a file that is not .npz (notes.txt, frame.png)",
    "duplicate-name": "a second map with an experiment name already used",
    "other-layers": "a map with another layer count (and without its own H)",
    "own-H": "a map that carries its own bed height H (any layer count allowed)",
    "upper-case-ext": "a valid map named .NPZ",
}
for _k, _about in ENTRY_KINDS.items():
    fault(CAMPAIGN, _k, _about)
fault(CAMPAIGN, "missing-dir", "the campaign folder does not exist / is a file")


@st.composite
def campaign_recipes(draw: Callable, min_valid: int = 0) -> Recipe:
    """A campaign folder mixing valid maps and broken entries; build it with :func:`build_campaign`."""
    n_valid = draw(st.integers(min_valid, 3))
    entries = [{"kind": "valid-map", "seed": i} for i in range(n_valid)]
    extra = draw(st.lists(st.sampled_from(list(ENTRY_KINDS)), min_size=0 if n_valid else 1, max_size=4))
    for k in extra:
        e: dict[str, Any] = {"kind": k, "seed": draw(st.integers(0, 9))}
        if k == "broken-map":
            e["map"] = draw(map_recipes().filter(lambda m: m.kind != "valid"))
        if k == "hidden-file":
            e["which"] = draw(st.sampled_from([".DS_Store", ".G-PP-50.npz.ab12.npz", ".G-PP-50.npz.ab12.partial"]))
        entries.append(e)
    kind = "missing-dir" if draw(st.integers(0, 15)) == 0 else (extra[0] if extra else "valid-map")
    n_layers = draw(st.sampled_from([15, 15, 5]))
    return Recipe(CAMPAIGN, kind, "", {"entries": entries, "n_layers": n_layers,
                                       "missing": kind == "missing-dir"})


def _loads(path: Path) -> bool:
    import warnings

    from granseg.maps import load_map

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load_map(path)
    except Exception:  # noqa: BLE001 - only whether it loads
        return False
    return True


def build_campaign(r: Recipe, root: Path, marker: str) -> tuple[Path, int]:
    """Build the campaign of recipe ``r`` under ``root``; return the folder and how many maps a
    successful load_campaign must return (every visible *.npz holding a valid map)."""
    d = root / "campaign"
    if r.args["missing"]:
        if r.args["entries"] and r.args["entries"][0]["seed"] % 2:
            d.write_bytes(b"a file, not a folder")
        return d, 0
    d.mkdir()
    n_layers = r.args["n_layers"]
    expected = 0
    names_used = 0

    def save(path: Path | bytes, **kw: Any) -> None:
        with open(path, "wb") as fh:
            fh.write(npz_bytes(valid_map_arrays(**kw)))

    for i, e in enumerate(r.args["entries"]):
        k, seed = e["kind"], e["seed"]
        name = f"X-{i:02d}"
        if k == "valid-map":
            save(d / f"{name}.npz", n_layers=n_layers, seed=seed, name=name)
            expected += 1
        elif k == "broken-map":
            build_map(e["map"], d / f"{name}.npz", marker)
            if _loads(d / f"{name}.npz"):  # some damage leaves a valid map (a flipped padding byte)
                expected += 1
        elif k == "hidden-file":
            (d / e["which"]).write_bytes(b"PK\x03\x04 half")
        elif k == "symlink-valid":
            target = root / f"elsewhere-{i}.npz"
            save(target, n_layers=n_layers, seed=seed, name=name)
            (d / f"{name}.npz").symlink_to(target)
            expected += 1
        elif k == "symlink-dangling":
            (d / f"{name}.npz").symlink_to(root / "moved-away.npz")
        elif k == "symlink-loop":
            (d / f"{name}.npz").symlink_to(d / f"{name}.npz")
        elif k == "symlink-dir":
            (d / f"{name}.npz").symlink_to(root)
        elif k == "non-utf8-name":
            save(os.fsencode(d) + b"/" + f"{name}-".encode() + b"\xff\xfe.npz", n_layers=n_layers, seed=seed,
                 name=name)
            expected += 1
        elif k == "subfolder":
            (d / f"sub{i}").mkdir()
            save(d / f"sub{i}" / "inner.npz", n_layers=n_layers, seed=seed, name=f"inner-{i}")
        elif k == "dir-named-npz":
            (d / f"{name}.npz").mkdir()
        elif k == "other-file":
            (d / f"notes{i}.txt").write_text("not a map")
        elif k == "duplicate-name":
            save(d / f"{name}.npz", n_layers=n_layers, seed=seed, name="X-00")
            save(d / f"{name}b.npz", n_layers=n_layers, seed=seed + 1, name="X-00")
            expected += 2
        elif k == "other-layers":
            save(d / f"{name}.npz", n_layers=3 if n_layers != 3 else 4, seed=seed, name=name)
            expected += 1
        elif k == "own-H":
            save(d / f"{name}.npz", n_layers=7, seed=seed, name=name, cell={"H": 0.042})
            expected += 1
        elif k == "upper-case-ext":
            save(d / f"{name}.NPZ", n_layers=n_layers, seed=seed, name=name)
        names_used += 1
    return d, expected


# --------------------------------------------------------------------------- (c) experiment.json

EXPERIMENT = "load_experiment"
NUMBER_FIELDS = ("rho_h", "rho_l", "c0", "M_g", "M_w", "fps", "particle_diameter_px", "t0", "wall_radius")
ARRAY_FIELDS = ("camera_matrix", "dist_coeffs", "window", "heavy_hsv", "light_lab")
EXP_TEXT_FIELDS = ("name", "heavy", "light")
EXP_FIELDS = (*EXP_TEXT_FIELDS, *NUMBER_FIELDS, *ARRAY_FIELDS)
for _k, _about in [
    ("valid", "the untouched experiment.json (must load)"),
    ("missing-field", "a field left out or null"),
    ("wrong-type", "a field of the wrong JSON type (string, bool, list, object)"),
    ("huge-number", "10**400 (an integer float() overflows) or 1e308 in a number or array field"),
    ("bad-number", "0, negative, NaN, Infinity, 1e-300 in a number field"),
    ("string-number", 'a number given as a string ("2450")'),
    ("nested-junk", "deeply nested lists or objects in a field"),
    ("bad-array", "an array field of the wrong shape, ragged, empty, or with NaN / text inside"),
    ("inverted-window", "window with x0 >= x1 or y0 >= y1, or outside the image"),
    ("not-an-object", "the document is a list, a number, a string or null"),
    ("invalid-json", "truncated JSON, a BOM, non-UTF-8 bytes, an empty file"),
    ("unknown-fields", "extra fields, '_help', duplicate keys"),
]:
    fault(EXPERIMENT, _k, _about)


def nested(depth: int) -> Any:
    v: Any = 1
    for i in range(depth):
        v = [v] if i % 2 else {"a": v}
    return v


@st.composite
def json_mutations(draw: Callable, entry: str, base: dict[str, Any], fields: tuple[str, ...],
                   numbers: tuple[str, ...], arrays: tuple[str, ...]) -> Recipe:
    """A mutation of the JSON object ``base``: the recipe's args hold the resulting document
    (``doc``, a Python object, or ``text``, raw bytes)."""
    kind = draw(st.sampled_from(kinds(entry)))
    doc: Any = json.loads(json.dumps(base))
    target = ""
    text: bytes | None = None
    if kind == "missing-field":
        target = draw(st.sampled_from([f for f in fields if f in doc]))
        if draw(st.booleans()):
            del doc[target]
        else:
            doc[target] = None
    elif kind == "wrong-type":
        target = draw(st.sampled_from(fields))
        doc[target] = draw(st.sampled_from([True, False, "abc", [], {}, [[1]], "", {"value": 1}]))
    elif kind == "huge-number":
        target = draw(st.sampled_from(numbers + arrays))
        big = draw(st.sampled_from([10**400, -(10**400), 1e308, 10**30]))
        if target in arrays and isinstance(doc.get(target), list):
            flat = doc[target]
            if flat and isinstance(flat[0], list):
                flat[0][0] = big
            elif flat:
                flat[0] = big
        else:
            doc[target] = big
    elif kind == "bad-number":
        target = draw(st.sampled_from(numbers))
        doc[target] = draw(st.sampled_from([0, -5, -1e-9, float("nan"), float("inf"), float("-inf"), 1e-300]))
    elif kind == "string-number":
        target = draw(st.sampled_from(numbers))
        doc[target] = str(doc.get(target, 1.0))
    elif kind == "nested-junk":
        target = draw(st.sampled_from(fields))
        doc[target] = nested(draw(st.integers(2, 60)))
    elif kind == "bad-array":
        target = draw(st.sampled_from(arrays))
        doc[target] = draw(st.sampled_from([[], [1, 2], [[1, 2], [3]], [float("nan")] * 4, ["a", "b", "c", "d"],
                                            [[1, 2, 3], [4, 5, 6], [7, 8, 9], [1, 1, 1]], [None, 1, 2, 3]]))
    elif kind == "inverted-window" and "window" in doc:
        target = "window"
        x0, y0, x1, y1 = doc["window"]
        doc["window"] = draw(st.sampled_from([[x1, y0, x0, y1], [x0, y1, x1, y0], [x0, y0, x0, y1],
                                              [-1e6, -1e6, 1e6, 1e6], [1e5, 1e5, 1e5 + 50, 1e5 + 50]]))
    elif kind == "not-an-object":
        doc = draw(st.sampled_from([[doc], 42, "experiment", None, []]))
    elif kind == "invalid-json":
        raw = json.dumps(doc).encode()
        text = draw(st.sampled_from([raw[: len(raw) // 2], b"\xef\xbb\xbf" + raw, raw.replace(b'"', b"\xff", 1), b"",
                                     b"{" * 100_000]))
    elif kind == "unknown-fields":
        doc["_help"] = {"x": 1}
        doc["junk" * draw(st.integers(1, 3))] = nested(3)
        raw = json.dumps(doc)
        text = (raw[:-1] + ', "name": 5}').encode() if draw(st.booleans()) else None
        target = "name" if text else ""
    names = (f"'{target}'", target) if target else ()
    return Recipe(entry, kind, target, {"doc": doc, "text": text}, names)


def write_json_recipe(r: Recipe, path: Path) -> None:
    if r.args["text"] is not None:
        path.write_bytes(r.args["text"])
    else:
        path.write_text(json.dumps(r.args["doc"]))  # allow_nan: NaN and Infinity literals, as users write


#: the experiment.json of the tiny rendered frames of the test world (test_fuzz renders them)
EXPERIMENT_BASE: dict[str, Any] = {
    "name": "fuzz", "heavy": "steel", "light": "pp", "rho_h": 7800.0, "rho_l": 946.0, "c0": 0.5, "M_g": 2.0,
    "M_w": 1.093, "fps": 0.5, "camera_matrix": [[360.0, 0.0, 202.5], [0.0, 360.0, 207.5], [0.0, 0.0, 1.0]],
    "dist_coeffs": [-0.12, 0.0043, 0.0004, -0.0003, 0.0], "window": [110.0, 60.0, 290.0, 360.0],
    "particle_diameter_px": 20.0,
}


def experiment_recipes(base: dict[str, Any] | None = None) -> st.SearchStrategy[Recipe]:
    return json_mutations(EXPERIMENT, base or EXPERIMENT_BASE, EXP_FIELDS, NUMBER_FIELDS, ARRAY_FIELDS)


def known_of_experiment(r: Recipe) -> str | None:
    """The open bug an experiment.json recipe may hit."""
    doc = r.args["doc"]
    if r.kind == "huge-number" and isinstance(doc, dict) and _huge_int(doc, r.target):
        return "overflow-json"
    if r.target == "particle_diameter_px" and r.kind in ("huge-number", "bad-number"):
        return "diameter-cv2"
    if r.target == "t0":
        return "t0-negative"
    return None


def _huge_int(doc: dict[str, Any], key: str) -> bool:
    """Whether ``doc[key]`` (or its first element) is an integer beyond float's range."""
    v = doc.get(key)
    while isinstance(v, list) and v:
        v = v[0]
    return isinstance(v, int) and not isinstance(v, bool) and abs(v) > 10**308


# the DEM config (dem.json): same mutations, its own fields
DEM_CONFIG = "dem_config"
for _k in kinds(EXPERIMENT):
    if _k not in ("inverted-window",):
        fault(DEM_CONFIG, _k, FAULTS[EXPERIMENT][_k].replace("experiment.json", "dem.json"))
DEM_FIELDS = ("types", "units", "flow_axis", "up_axis", "side_walls", "bottom_z", "timestep", "lid_force",
              "plate_speed", "diameter", "gravity")
DEM_NUMBERS = ("bottom_z", "timestep", "lid_force", "plate_speed", "diameter", "gravity")


def dem_config_recipes(base: dict[str, Any]) -> st.SearchStrategy[Recipe]:
    return json_mutations(DEM_CONFIG, base, DEM_FIELDS, DEM_NUMBERS, ("side_walls", "units", "types"))


# frames of an image directory
FRAMES = "analyze (frames)"
for _k, _about in [
    ("valid", "the rendered frames as they are"),
    ("truncated-frame", "one PNG cut short"),
    ("empty-frame", "one zero-byte .png"),
    ("not-an-image", "a .png that holds text"),
    ("grayscale-frame", "one frame saved as grayscale"),
    ("other-size-frame", "one frame of another size (the first or a later one)"),
    ("dir-named-png", "a folder named frame.png"),
    ("no-frames", "experiment.json alone"),
    ("non-utf8-frame", "a frame whose name is not UTF-8"),
    ("hidden-frame", "a hidden ._frame.png (macOS resource fork)"),
]:
    fault(FRAMES, _k, _about)


@st.composite
def frames_recipes(draw: Callable) -> Recipe:
    kind = draw(st.sampled_from(kinds(FRAMES)))
    which = draw(st.sampled_from(["first", "later"]))
    known = {"grayscale-frame": "grayscale-frames", "non-utf8-frame": "non-utf8-name",
             "other-size-frame": "frame-size-window" if which == "first" else None}.get(kind)
    return Recipe(FRAMES, kind, "", {"which": which, "keep": draw(st.floats(0.05, 0.95))}, (), known)


# --------------------------------------------------------------------------- (d) the command line

CLI_PREFIX = "cli "
#: subcommands not run by the fuzz (demo: a fixed script over embedded data, minutes long)
CLI_SKIP = {"demo"}
#: options not fuzzed: --dask connects to a scheduler (a bogus address waits on the network)
OPTION_SKIP = {"--dask", "--help", "-h", "--verbose", "-v"}

NUMBER_CLASSES = tuple(BAD_ARG_NUMBERS)
PATH_CLASSES = ("missing", "under-a-file", "proc", "existing", "directory", "empty", "non-utf8", "valid",
                "dev-null", "long-name")
TEXT_CLASSES = ("empty", "spaces", "dash", "non-utf8", "huge", "valid")
SPECIAL_VALUES: dict[str, dict[str, list[str]]] = {
    "--set": {"unknown-name": ["bogus=1"], "out-of-range": ["k=-1", "c0=2", "D_p=1", "H=0"],
              "nan": ["k=nan"], "no-equals": ["k"], "empty-name": ["=1"], "huge": ["rho_h=1e400"],
              "word": ["k=abc"], "valid": ["k=0.6"]},
    "--grid": {"empty-values": ["k="], "word": ["k=abc"], "empty-name": ["=0.5"], "nan-inf": ["k=nan,inf"],
               "unknown-name": ["bogus=1"], "negative": ["k=-1"], "one-point": ["k=0.7"], "no-equals": ["k"],
               "huge-grid": ["k=" + ",".join(["0.7"] * 200)]},
    "--bounds": {"inverted": ["k=1:0"], "nan": ["k=nan:1"], "no-colon": ["k=0.3"], "unknown-name": ["bogus=0:1"],
                 "equal": ["k=0.5:0.5"], "negative": ["k=-1:0"], "word": ["k=a:b"]},
    "--window": {"too-few": ["1,2"], "words": ["a,b,c,d"], "inverted": ["10,10,5,5"], "nan": ["nan,0,1,1"],
                 "overflow": ["1e400,0,1,2"], "empty": [""], "valid": ["110,60,290,360"]},
    "--pattern": {"word": ["axb"], "one": ["1x6"], "huge": ["100000x100000"], "zero": ["0x0"], "negative": ["-9x6"],
                  "valid": ["9x6"]},
    "--causes": {"unknown": ["bogus"]},
}


def _is_path_option(action: argparse.Action) -> bool:
    text = f"{action.metavar or ''} {action.dest} {action.help or ''}".lower()
    return any(w in text for w in (".json", ".npz", "dir", "file", "stem", "path", "folder", "csv", "out"))


def option_kinds(action: argparse.Action) -> tuple[str, tuple[str, ...]]:
    """The value class family of an option and its classes (what the fuzz draws for it)."""
    opt = max(action.option_strings, key=len) if action.option_strings else action.dest
    if opt in SPECIAL_VALUES:
        return "special", tuple(SPECIAL_VALUES[opt])
    if action.nargs == 0:
        return "flag", ("given",)
    if action.choices is not None:
        return "choice", ("valid", "bogus", "empty")
    if action.type in (int, float):
        return "number", NUMBER_CLASSES
    if action.type is not None:
        return "text", TEXT_CLASSES
    if _is_path_option(action):
        return "path", PATH_CLASSES
    return "text", TEXT_CLASSES


def cli_parsers() -> dict[str, argparse.ArgumentParser]:
    """Every subcommand's parser, by name (from granseg.cli.build_parser)."""
    from granseg.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {name: p for name, p in sub.choices.items() if name not in CLI_SKIP}


def cli_actions(p: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in p._actions if not isinstance(a, argparse._HelpAction)
            and not (set(a.option_strings) & OPTION_SKIP)]


def register_cli() -> None:
    for name, p in cli_parsers().items():
        entry = CLI_PREFIX + name
        fault(entry, "no-arguments", "the command alone")
        fault(entry, "unknown-option", "an option the command does not have")
        fault(entry, "duplicate-option", "an option given twice")
        for action in cli_actions(p):
            opt = max(action.option_strings, key=len) if action.option_strings else action.dest
            family, classes = option_kinds(action)
            for c in classes:
                fault(entry, f"{opt}={c}", f"{opt} ({family}): {c}")


register_cli()


@st.composite
def cli_recipes(draw: Callable, command: str) -> Recipe:
    """An argument vector for ``command``: most options at valid or cheap values, one to three
    drawn from the edge classes; args hold [(option or positional dest, class)]."""
    entry = CLI_PREFIX + command
    kind = draw(st.sampled_from(kinds(entry)))
    p = cli_parsers()[command]
    chosen: list[tuple[str, str]] = []
    if kind not in ("no-arguments", "unknown-option", "duplicate-option"):
        chosen.append(tuple(kind.split("=", 1)))  # type: ignore[arg-type]
        others = [a for a in cli_actions(p) if a.option_strings]
        for action in draw(st.lists(st.sampled_from(others), max_size=2, unique_by=lambda a: a.dest)) if others else []:
            opt = max(action.option_strings, key=len)
            if opt != chosen[0][0]:
                chosen.append((opt, draw(st.sampled_from(option_kinds(action)[1]))))
    seed = draw(st.integers(0, 2**16))
    return Recipe(entry, kind, chosen[0][0] if chosen else "", {"chosen": chosen, "seed": seed})


# --------------------------------------------------------------------------- (e) public API calls

API_EDGES: dict[str, Any] = {**BAD_NUMBERS, "zero-array": np.zeros(0), "2d-array": np.ones((2, 2)),
                             "object": object(), "bytes": b"\xff", "path-missing": Path("/no/such/path.npz"),
                             "very-negative-int": -(2**70), "numpy-int": np.int64(3), "complex": 1 + 2j}

API_KWARGS: dict[str, tuple[str, ...]] = {
    "granseg.simulate": ("t", "n_cells", "rtol", "atol", "k", "delta_over_H", "c0", "rho_h", "rho_l", "M_w", "H",
                         "rpm", "D_p", "phi_s", "bogus"),
    "granseg.steady_state": ("n_cells", "k", "c0", "rho_h", "delta_over_H", "bogus"),
    "granseg.sweep": ("grid", "base", "cases", "t", "measured", "n_layers", "n_cells", "rtol", "threads",
                      "progress"),
    "granseg.calibrate": ("grid", "bounds", "base", "n_cells", "rtol", "atol", "fd_rel", "max_nfev", "errors",
                          "velocity", "velocity_shape", "per_experiment", "refine"),
    "granseg.diagnose": ("causes", "n_cells", "rtol", "max_nfev", "gain_threshold", "excess_threshold",
                         "coherence_alpha", "coherence_share", "json", "report", "velocity"),
    "granseg.load_map": ("path",),
    "granseg.load_campaign": ("directory",),
    "granseg.analyze": ("smooth", "smooth_seconds", "every", "every_seconds", "preview_count", "workers", "out",
                        "detections"),
    "granseg.load_velocity": ("path",),
    "granseg.measure_velocity": ("D_p", "H", "workers"),
    "granseg.load_dem": ("dumps", "config", "name"),
}
for _entry, _kws in API_KWARGS.items():
    for _kw in _kws:
        for _c in API_EDGES:
            fault(_entry, f"{_kw}={_c}", f"{_kw} = {_c}")


@st.composite
def api_recipes(draw: Callable, entry: str) -> Recipe:
    """One to two keyword arguments of ``entry`` set to edge values (args: {kw: class})."""
    kind = draw(st.sampled_from(kinds(entry)))
    kw, cls = kind.split("=", 1)
    chosen = {kw: cls}
    if draw(st.booleans()):
        kw2 = draw(st.sampled_from(API_KWARGS[entry]))
        chosen.setdefault(kw2, draw(st.sampled_from(list(API_EDGES))))
    return Recipe(entry, kind, kw, {"chosen": chosen}, (kw,))


# --------------------------------------------------------------------------- the count


def count_table() -> str:
    rows = ["| entry point | fault kinds |", "|---|---:|"]
    total = 0
    for entry in sorted(FAULTS, key=lambda e: (e.startswith("cli "), e.startswith("granseg."), e)):
        n = len(FAULTS[entry])
        total += n
        rows.append(f"| `{entry}` | {n} |")
    rows.append(f"| **total** ({len(FAULTS)} entry points) | **{total}** |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", action="store_true", help="print the number of fault kinds per entry point")
    ap.add_argument("--list", action="store_true", help="also list every kind")
    args = ap.parse_args(argv)
    print(count_table())
    if args.list:
        for entry in sorted(FAULTS):
            print(f"\n## {entry}\n")
            for k, about in FAULTS[entry].items():
                print(f"- `{k}`: {about}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
