"""Issue 14, "nothing aborts, hangs or hides": map files that are damaged, forged, half written or
missing are refused naming the file (and key), never read as maps, never dropped silently."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import textwrap
import time
import warnings
import zipfile

import numpy as np
import pytest

from granseg._io import PARTIAL_SUFFIX, atomic_path, atomic_write, save_npz
from granseg.errors import MapFormatError, StaleFileWarning
from granseg.maps import MAX_ARRAY_BYTES, Map, load_campaign, load_map, save_map
from test_maps import fields  # one valid map's DATA fields, as the map tests build them


@pytest.fixture
def campaign(tmp_path):
    """A folder with two valid maps, G-PP-50.npz and G-PP-30.npz."""
    d = tmp_path / "campaign"
    d.mkdir()
    save_map(d / "G-PP-50.npz", **fields("G-PP-50"))
    save_map(d / "G-PP-30.npz", **fields("G-PP-30", seed=1))
    return d


def npy_bytes(header: dict, data: bytes) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + data


# --------------------------------------------------------------------------- stale temporary files


def test_a_stale_hidden_temp_file_is_skipped_and_named(campaign):
    stale = campaign / ".G-PP-50.npz.abcd.npz"  # what an interrupted write of the old writer left
    stale.write_bytes(b"PK\x03\x04 garbage, half a map")
    with pytest.warns(StaleFileWarning, match=r"\.G-PP-50\.npz\.abcd\.npz") as record:
        c = load_campaign(campaign)
    assert c.names == ["G-PP-30", "G-PP-50"]
    assert str(stale) in str(record[0].message)


def test_other_hidden_files_are_skipped_quietly(campaign):
    (campaign / ".DS_Store").write_bytes(b"\x00\x01")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_campaign(campaign).names == ["G-PP-30", "G-PP-50"]


def test_the_temp_file_of_a_running_write_is_not_a_map(campaign):
    """While a write runs, nothing in the folder that ends in .npz is the half-written file, and
    the writer still sees the destination's name and extension (format chosen by name)."""
    seen = {}

    def write(tmp):
        seen["tmp"] = tmp
        seen["npz"] = sorted(p.name for p in campaign.glob("*.npz"))
        with open(tmp, "wb") as fh:
            np.savez(fh, **{k: (np.str_(v) if isinstance(v, str) else v) for k, v in fields("G-PP-70").items()})

    atomic_write(campaign / "G-PP-70.npz", write)
    tmp = seen["tmp"]
    assert tmp.name == "G-PP-70.npz" and tmp.parent.parent == campaign
    assert tmp.parent.name.startswith(".") and tmp.parent.name.endswith(PARTIAL_SUFFIX)
    assert seen["npz"] == ["G-PP-30.npz", "G-PP-50.npz"]
    assert sorted(os.listdir(campaign)) == ["G-PP-30.npz", "G-PP-50.npz", "G-PP-70.npz"]
    with atomic_path(campaign / "shot.png") as tmp:
        assert tmp.suffix == ".png"  # cv2.imwrite and the video encoders pick the format by it
        tmp.write_bytes(b"png")


def test_a_failed_write_leaves_nothing_behind(campaign):
    def fail(tmp):
        tmp.write_bytes(b"PK\x03\x04 half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(campaign / "G-PP-70.npz", fail)
    assert sorted(os.listdir(campaign)) == ["G-PP-30.npz", "G-PP-50.npz"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_campaign(campaign).names == ["G-PP-30", "G-PP-50"]


def test_a_killed_write_leaves_nothing_a_reader_takes_for_a_map(campaign):
    """A process killed mid-write cannot clean up: what it leaves is hidden, ends in .partial,
    and load_campaign reads the real maps and names the leftover."""
    script = textwrap.dedent(f"""
        import os
        from granseg._io import atomic_write
        def write(tmp):
            tmp.write_bytes(b"PK\\x03\\x04 half a map")
            os._exit(3)
        atomic_write({str(campaign / 'G-PP-70.npz')!r}, write)
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 3, run.stderr
    left = [p for p in campaign.iterdir() if p.name not in ("G-PP-30.npz", "G-PP-50.npz")]
    assert len(left) == 1 and left[0].name.startswith(".G-PP-70.npz.") and left[0].name.endswith(PARTIAL_SUFFIX)
    assert sorted(p.name for p in campaign.glob("*.npz")) == ["G-PP-30.npz", "G-PP-50.npz"]
    with pytest.warns(StaleFileWarning, match="interrupted") as record:
        assert load_campaign(campaign).names == ["G-PP-30", "G-PP-50"]
    assert str(left[0]) in str(record[0].message)
    save_map(campaign / "G-PP-70.npz", **fields("G-PP-70"))  # the next write is not blocked by it


# --------------------------------------------------------------------------- damaged files


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.99, 40])
def test_a_truncated_map_is_refused_naming_it(campaign, keep):
    path = campaign / "G-PP-50.npz"
    data = path.read_bytes()
    n = keep if isinstance(keep, int) else int(len(data) * keep)
    path.write_bytes(data[:n])
    with pytest.raises(MapFormatError) as info:
        load_map(path)
    assert str(path) in str(info.value)
    with pytest.raises(MapFormatError) as info:
        load_campaign(campaign)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("compressed", [False, True])
def test_a_corrupted_member_is_refused_naming_file_and_key(tmp_path, compressed):
    path = tmp_path / "a.npz"
    arrays = {k: (np.str_(v) if isinstance(v, str) else v) for k, v in fields(n_t=400).items()}
    with open(path, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **arrays)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("c.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra) + 200  # inside c's data
    data[start:start + 64] = bytes(64)
    path.write_bytes(bytes(data))
    with pytest.raises(MapFormatError, match="'c'") as info_:
        load_map(path)
    assert str(path) in str(info_.value)


def test_a_file_that_is_not_an_archive_is_refused_naming_it(tmp_path):
    path = tmp_path / "a.npz"
    path.write_bytes(b"this is not a zip file at all")
    with pytest.raises(MapFormatError, match="not a readable .npz") as info:
        load_map(path)
    assert str(path) in str(info.value)


def test_a_forged_huge_header_is_refused_without_allocating(tmp_path):
    """An array header claiming 10^9 x 15 float64 (112 GB): refused from the header, at once."""
    path = tmp_path / "forged.npz"
    good = {k: (np.str_(v) if isinstance(v, str) else v) for k, v in fields().items()}
    with zipfile.ZipFile(path, "w") as zf:
        for key, value in good.items():
            buf = io.BytesIO()
            np.save(buf, value)
            if key == "c":
                zf.writestr("c.npy", npy_bytes({"descr": "<f8", "fortran_order": False, "shape": (10**9, 15)},
                                               bytes(64)))
            else:
                zf.writestr(f"{key}.npy", buf.getvalue())
    start = time.perf_counter()
    with pytest.raises(MapFormatError, match=r"field 'c'.*1000000000, 15") as info:
        load_map(path)
    assert time.perf_counter() - start < 5.0
    assert str(path) in str(info.value) and "GiB" in str(info.value)
    assert 10**9 * 15 * 8 > MAX_ARRAY_BYTES


def test_a_header_declaring_more_than_the_member_holds_is_refused(tmp_path):
    path = tmp_path / "short.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("c.npy", npy_bytes({"descr": "<f8", "fortran_order": False, "shape": (1000, 15)}, bytes(80)))
    with pytest.raises(MapFormatError, match=r"field 'c'.*truncated") as info:
        load_map(path)
    assert str(path) in str(info.value)


# --------------------------------------------------------------------------- entries that are not maps


def test_a_dangling_symlink_is_refused_naming_it(campaign):
    link = campaign / "G-PP-70.npz"
    link.symlink_to(campaign / "moved-away.npz")
    with pytest.raises(FileNotFoundError, match="symbolic link") as info:
        load_campaign(campaign)
    assert str(link) in str(info.value)
    with pytest.raises(FileNotFoundError, match="symbolic link") as info:
        load_map(link)
    assert str(link) in str(info.value)


def test_a_symlink_to_a_map_is_read(campaign, tmp_path):
    elsewhere = tmp_path / "G-PP-70.npz"
    save_map(elsewhere, **fields("G-PP-70"))
    (campaign / "G-PP-70.npz").symlink_to(elsewhere)
    assert load_campaign(campaign).names == ["G-PP-30", "G-PP-50", "G-PP-70"]


def test_a_folder_named_like_a_map_is_refused_naming_it(campaign):
    (campaign / "G-PP-70.npz").mkdir()
    with pytest.raises(MapFormatError, match="not a file") as info:
        load_campaign(campaign)
    assert str(campaign / "G-PP-70.npz") in str(info.value)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file")
def test_an_unreadable_map_is_refused_naming_it(campaign):
    path = campaign / "G-PP-50.npz"
    path.chmod(0)
    try:
        with pytest.raises(MapFormatError) as info:
            load_campaign(campaign)
        assert str(path) in str(info.value)
    finally:
        path.chmod(0o644)


# --------------------------------------------------------------------------- smoothing_frames


def test_a_fractional_smoothing_width_is_refused_naming_the_field(tmp_path):
    with pytest.raises(MapFormatError, match="'smoothing_frames'.*3.7"):
        save_map(tmp_path / "a.npz", **fields(), smoothing_frames=3.7)
    with pytest.raises(MapFormatError, match="'smoothing_frames'.*3.7"):
        Map.from_arrays({**fields(), "smoothing_frames": 3.7})
    raw = {k: (np.str_(v) if isinstance(v, str) else v) for k, v in fields().items()}
    save_npz(tmp_path / "b.npz", {**raw, "smoothing_frames": np.float64(3.7)})
    with pytest.raises(MapFormatError, match="'smoothing_frames'.*3.7") as info:
        load_map(tmp_path / "b.npz")
    assert str(tmp_path / "b.npz") in str(info.value)
    for bad in (np.nan, np.inf, True, "3"):
        with pytest.raises(MapFormatError, match="'smoothing_frames'"):
            Map.from_arrays({**fields(), "smoothing_frames": bad})


def test_a_whole_float_smoothing_width_is_taken_as_that_integer(tmp_path):
    raw = {k: (np.str_(v) if isinstance(v, str) else v) for k, v in fields().items()}
    save_npz(tmp_path / "a.npz", {**raw, "smoothing_frames": np.float64(3.0)})
    m = load_map(tmp_path / "a.npz")
    assert m.smoothing_frames == 3 and isinstance(m.smoothing_frames, int)
    with pytest.raises(MapFormatError, match="'smoothing_frames'.*odd"):
        Map.from_arrays({**fields(), "smoothing_frames": 4.0})
