"""Video == frames, camera calibration, and every bad input named clearly."""

from __future__ import annotations

import json
import logging
import re
import shutil
import warnings

import cv2
import numpy as np
import pytest

from granseg._io import OutputExistsError
from granseg.cli import main
from granseg.errors import BadFrame, QualityWarning
from granseg.measure import BadFrameWarning, analyze, calibrate_camera
from granseg.measure.camera import Undistorter, find_checkerboard
from granseg.measure.stills import SENSOR_BITS, decode_still, sensor_bits, to_8bit
from granseg.synth import default_camera, render_checkerboard, render_frames

SMALL = dict(heavy="ceramic", light="pp", particle_diameter_px=20, image_size=(400, 480))


def _map(n_t=4):
    c = np.zeros((n_t, 15))
    c[:, 8:] = 1.0
    c[2:] = 0.5
    return c


def _as_video(d, video):
    """The frames of folder ``d`` as a lossless (FFV1) ``video``, its experiment.json beside it."""
    video.parent.mkdir()
    images = [cv2.imread(str(p)) for p in sorted(d.glob("*.png"))]
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, images[0].shape[1::-1])
    for img in images:
        writer.write(img)
    writer.release()
    (video.parent / "experiment.json").write_text((d / "experiment.json").read_text())
    return video


@pytest.fixture
def frames(tmp_path):
    d = tmp_path / "run"
    render_frames(_map(), seed=1, out_dir=d, **SMALL)
    return d


def test_video_gives_the_same_map_as_its_frames(frames, tmp_path):
    images = [cv2.imread(str(p)) for p in sorted(frames.glob("*.png"))]
    video = tmp_path / "vid" / "run.avi"
    video.parent.mkdir()
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 2.0, images[0].shape[1::-1])
    for img in images:
        writer.write(img)
    writer.release()
    (video.parent / "experiment.json").write_text((frames / "experiment.json").read_text())
    a = analyze(frames, save=False, progress=False)
    b = analyze(video, save=False, progress=False, preview=tmp_path / "previews")
    assert np.array_equal(a.n, b.n) and np.array_equal(a.n_heavy, b.n_heavy)
    assert np.allclose(a.t, b.t)
    # each previewed frame of the video has its own file (they once all went to preview_run.png)
    assert sorted(p.name for p in (tmp_path / "previews").iterdir()) == [f"preview_run_{i}.png" for i in range(4)]


def test_cli_writes_map_and_refuses_to_overwrite(frames, capsys):
    from granseg.maps import load_map

    assert main(["analyze", str(frames), "--smooth", "3", "--no-progress", "--preview", str(frames / "prev")]) == 0
    m = load_map(frames / "map.npz")
    assert m.smoothing_frames == 3 and m.c.shape == (4, 15)
    assert len(list((frames / "prev").glob("*.png"))) == 4
    before = (frames / "map.npz").read_bytes()
    assert main(["analyze", str(frames), "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err
    assert (frames / "map.npz").read_bytes() == before
    assert main(["analyze", str(frames), "--no-progress", "--force", "--smooth", "1"]) == 0


def test_maps_go_into_a_campaign_folder_with_smoothing_in_seconds(frames, tmp_path, capsys):
    """`--out CAMPAIGN/` names the map after the experiment (no renaming by hand), and a
    smoothing window in seconds becomes the odd frame count nearest to it."""
    from granseg.maps import load_campaign
    from granseg.measure.pipeline import frames_for_seconds

    fps = json.loads((frames / "experiment.json").read_text())["fps"]
    name = json.loads((frames / "experiment.json").read_text())["name"]
    camp = tmp_path / "campaign"
    assert main(["analyze", str(frames), "--out", f"{camp}/", "--smooth-seconds", str(2.9 / fps),
                 "--no-progress"]) == 0
    assert "smoothing: 3 frames" in capsys.readouterr().out
    c = load_campaign(camp)
    assert [m.path.name for m in c.maps] == [f"{name}.npz"] and c.maps[0].smoothing_frames == 3
    assert main(["analyze", str(frames), "--out", str(camp), "--no-progress"]) == 2  # a folder: same name, kept
    with pytest.raises(SystemExit):
        main(["analyze", str(frames), "--smooth", "3", "--smooth-seconds", "5", "--no-progress"])
    assert "not allowed with" in capsys.readouterr().err  # argparse names the clash
    assert [frames_for_seconds(s, 1.0) for s in (0, 0.4, 1.9, 2.1, 4.9, 5.9, 6.1)] == [1, 1, 1, 3, 5, 5, 7]
    with pytest.raises(ValueError, match="smooth_seconds"):
        frames_for_seconds(-1, 1.0)


def test_every_nth_frame_gives_the_rows_of_those_frames(tmp_path, capsys):
    """`--every N` analyses frames 0, N, 2N... of a frames folder or a video alone: the same
    counts as those rows of the whole run, rows N / fps apart, and the detections name the
    recording's frames."""
    import csv

    from granseg.maps import load_map

    d = tmp_path / "run"
    render_frames(_map(7), seed=3, out_dir=d, **SMALL)
    fps = json.loads((d / "experiment.json").read_text())["fps"]
    whole = analyze(d, save=False, progress=False)
    video = _as_video(d, tmp_path / "vid" / "run.avi")
    for source in (d, video):
        third = analyze(source, every=3, save=False, progress=False)
        assert np.array_equal(third.n, whole.n[::3]) and np.array_equal(third.n_heavy, whole.n_heavy[::3])
        assert np.allclose(third.t, whole.t[::3]) and third.every == 3
        assert third.quality.figures["frames_every"] == 3 and whole.quality.figures["frames_every"] == 1
    assert analyze(d, every=99, save=False, progress=False).n.shape == (1, 15)  # the first frame alone
    assert main(["analyze", str(d), "--every-seconds", str(2.2 / fps), "--detections", str(tmp_path / "det.csv"),
                 "--no-progress"]) == 0
    assert "one frame in 2 analysed" in capsys.readouterr().out
    m = load_map(d / "map.npz")
    assert m.c.shape == (4, 15) and np.isclose(m.fps, fps / 2) and np.allclose(m.t, whole.t[::2])
    with open(tmp_path / "det.csv", newline="") as f:
        assert sorted({int(r["frame"]) for r in csv.DictReader(f)}) == [0, 2, 4, 6]
    for bad, message in ((0, "every .CLI --every.: expected a whole number from 1 to 2147483647"),
                         (2.5, "every .CLI --every."), (True, "every .CLI --every.")):
        with pytest.raises(ValueError, match=message):
            analyze(d, every=bad, save=False, progress=False)
    for bad in (0, -1.0, float("nan"), "3", True):
        with pytest.raises(ValueError, match="every_seconds .CLI --every-seconds.: expected a duration > 0 s"):
            analyze(d, every_seconds=bad, save=False, progress=False)
    with pytest.raises(SystemExit):
        main(["analyze", str(d), "--every", "2", "--every-seconds", "5", "--no-progress"])
    assert "not allowed with" in capsys.readouterr().err


def test_frames_filmed_before_the_plate_started_are_left_out(tmp_path, capsys):
    """A negative t0 (the camera started first) leaves out the frames filmed before the plate
    moved: a recording that opens with three frames of the bed at rest, t0 = -2.5 frames, gives
    the map of the run without them, its rows half a frame later; from a frames folder and from a
    video alike, and the velocity tracking's detection skips them too."""
    import csv

    from granseg.measure.pipeline import detect_frames

    d = tmp_path / "run"
    render_frames(_map(5), seed=4, out_dir=d, **SMALL)
    exp = json.loads((d / "experiment.json").read_text())
    fps = exp["fps"]
    whole = analyze(d, save=False, progress=False)
    early = tmp_path / "early"
    early.mkdir()
    pngs = sorted(d.glob("*.png"))
    for k, p in enumerate([pngs[0]] * 3 + pngs):  # three frames of the bed at rest, then the run, numbered on
        shutil.copy(p, early / f"frame_{k:04d}.png")
    (early / "experiment.json").write_text(json.dumps({**exp, "t0": -2.5 / fps}))
    video = _as_video(early, tmp_path / "vid" / "run.avi")
    for source in (early, video):
        late = analyze(source, save=False, progress=False)
        assert np.array_equal(late.n, whole.n) and np.array_equal(late.n_heavy, whole.n_heavy)
        assert np.allclose(late.t, whole.t + 0.5 / fps) and late.first == 3
        assert late.quality.figures["frames_first"] == 3 and whole.quality.figures["frames_first"] == 0
        assert len(detect_frames(source, progress=False).spheres) == len(pngs)
    assert main(["analyze", str(early), "--every", "2", "--detections", str(tmp_path / "det.csv"),
                 "--no-progress"]) == 0
    assert "the first 3 frames, filmed before the plate started (t0 < 0), left out" in capsys.readouterr().out
    with open(tmp_path / "det.csv", newline="") as f:
        assert sorted({int(r["frame"]) for r in csv.DictReader(f)}) == [3, 5, 7]  # the recording's frames
    for t0 in (-(len(pngs) + 3) / fps, -1e300):  # the plate starts after the last frame
        (early / "experiment.json").write_text(json.dumps({**exp, "t0": t0}))
        with pytest.raises(ValueError, match="field 't0': .* puts the plate's start after the recording's last frame"):
            analyze(early, save=False, progress=False)


def _timed_video(d, video, seconds, fps=None):
    """The frames of folder ``d`` as a lossless ``video`` played at 30 frames/s, frame k stamped
    ``seconds[k]``: PNG in QuickTime (.mov, which records the frame count) or FFV1 in Matroska
    (.mkv, which keeps none). Its experiment.json is the folder's with ``fps`` (None: the
    stream's rate, as filmed in real time)."""
    import fractions

    av = pytest.importorskip("av")
    video.parent.mkdir()
    images = [cv2.imread(str(p)) for p in sorted(d.glob("*.png"))]
    mkv = video.suffix == ".mkv"
    with av.open(str(video), "w", options={} if mkv else {"movflags": "faststart"}) as container:  # its index first
        codec, pix_fmt = ("ffv1", "bgr0") if mkv else ("png", "rgb24")
        stream = container.add_stream(codec, rate=30)
        stream.width, stream.height, stream.pix_fmt = images[0].shape[1], images[0].shape[0], pix_fmt
        stream.time_base = fractions.Fraction(1, 1000)
        for img, at in zip(images, seconds, strict=True):
            frame = av.VideoFrame.from_ndarray(img, format="bgr24")
            frame.pts, frame.time_base = round(1000 * at), fractions.Fraction(1, 1000)
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    (video.parent / "experiment.json").write_text(json.dumps({**json.loads((d / "experiment.json").read_text()),
                                                             "fps": fps}))
    return video


def test_a_video_filmed_at_an_uneven_rate_has_the_times_of_its_stamps(tmp_path, caplog):
    """A video whose own time stamps stray from an even rate (a phone slowing from 30 to 10 frames/s
    halfway) gives a map whose times are the stamps, and passes frame_times; the same frames stamped
    evenly give k / fps. The same uneven video given fps = 0.5 (played 60 times faster than filmed:
    its stamps count playback) cannot be timed by them: frame_times fails and names it. An even
    time-lapse passes; a frames folder tells no times and is not checked."""
    from granseg.measure import quality

    d = tmp_path / "run"
    render_frames(_map(8), seed=5, out_dir=d, **SMALL)
    even = analyze(_timed_video(d, tmp_path / "even" / "run.mov", np.arange(8) / 30), save=False, progress=False)
    (check,) = [c for c in even.quality.checks if c.name == "frame_times"]
    assert check.passed and check.value < 0.2 * quality.FRAME_TIMES_SHARE  # stamps rounded to the ms
    assert even.quality.figures["frame_times_from_stamps"] is False
    np.testing.assert_allclose(np.diff(even.t), 1 / 30, rtol=1e-3)  # the stream's rate, from stamps in ms
    uneven_at = np.r_[np.arange(4) / 30, 3 / 30 + np.arange(1, 5) / 10]
    with caplog.at_level(logging.INFO):
        uneven = analyze(_timed_video(d, tmp_path / "uneven" / "run.mov", uneven_at), save=False, progress=False)
    assert "times from the stamps" in caplog.text
    (check,) = [c for c in uneven.quality.checks if c.name == "frame_times"]
    assert check.passed and check.value == 0.0 and uneven.quality.ok
    assert uneven.quality.figures["frame_times_uneven"] > 3 * quality.FRAME_TIMES_SHARE
    assert uneven.quality.figures["frame_times_from_stamps"] is True
    assert np.array_equal(uneven.n, even.n) and uneven.t[0] == even.t[0]  # the same frames from the same start
    np.testing.assert_allclose(uneven.t - uneven.t[0], uneven_at, atol=1e-3)  # the stamps, to the ms
    lapse = tmp_path / "lapse" / "run.mov"
    _timed_video(d, lapse, uneven_at, fps=0.5)
    caplog.clear()
    with pytest.warns(QualityWarning, match="frame_times"), caplog.at_level(logging.WARNING):
        played = analyze(lapse, save=False, progress=False)
    assert "stamps count playback" in caplog.text
    (check,) = [c for c in played.quality.checks if c.name == "frame_times"]
    assert not check.passed and check.value > 3 * quality.FRAME_TIMES_SHARE
    np.testing.assert_allclose(np.diff(played.t), 2.0)  # frames counted at the 0.5 fps given
    assert "frame_times" in quality.ADVICE and "-fps_mode cfr" in quality.ADVICE["frame_times"]
    _timed_video(d, tmp_path / "even-lapse" / "run.mov", np.arange(8) / 30, fps=0.5)
    assert [c.passed for c in analyze(tmp_path / "even-lapse" / "run.mov", save=False,
                                      progress=False).quality.checks if c.name == "frame_times"] == [True]
    assert "frame_times" not in {c.name for c in analyze(d, save=False, progress=False).quality.checks}


def test_a_video_started_before_the_plate_at_an_uneven_rate_is_timed_from_the_plate_by_its_stamps(tmp_path, caplog):
    """A negative t0 cuts a video's frames before the plate's start by counting them at fps, before
    any stamp is read. A phone that filmed its wait at 10 frames/s, then 30 (fps 30), cut at
    t0 = -0.1 s: the three frames counted are 0.3 s of filming, so the map's first row is 0.2 s
    after the plate started and every row is t0 plus its own stamp (it read 0 before). Where the
    stamps put the first frame kept before the plate started (30 frames/s filmed, 20 given), the
    times stay counted at fps, and frame_times fails and says why (a map's times are >= 0)."""
    c = np.zeros((12, 15))
    c[:, 8:] = 1.0  # stratified throughout: every frame kept shows the start's classes
    d = tmp_path / "run"
    render_frames(c, seed=5, out_dir=d, **SMALL)

    def started_before(video, t0):
        exp = video.parent / "experiment.json"
        exp.write_text(json.dumps({**json.loads(exp.read_text()), "t0": t0}))
        return video

    slow_then_fast = np.r_[np.arange(5) * 0.1, 0.4 + np.arange(1, 8) / 30]
    video = started_before(_timed_video(d, tmp_path / "slow" / "run.mkv", slow_then_fast, fps=30), -0.1)
    with caplog.at_level(logging.INFO):
        slow = analyze(video, save=False, progress=False)
    np.testing.assert_allclose(slow.t, -0.1 + slow_then_fast[3:], atol=1e-3)
    assert slow.first == 3 and slow.quality.ok and "by the video's stamps" in caplog.text
    assert slow.experiment.t0 == pytest.approx(0.2, abs=1e-3)
    fast_then_slow = np.r_[np.arange(6) / 30, 5 / 30 + np.arange(1, 7) * 0.1]
    video = started_before(_timed_video(d, tmp_path / "fast" / "run.mkv", fast_then_slow, fps=20), -0.1)
    caplog.clear()
    with pytest.warns(QualityWarning, match="frame_times"), caplog.at_level(logging.WARNING):
        fast = analyze(video, save=False, progress=False)
    assert "0.033 s before the plate started" in caplog.text and fast.first == 2
    assert [ch.name for ch in fast.quality.failed] == ["frame_times"]
    np.testing.assert_allclose(fast.t, np.arange(10) / 20)  # from t0 = -0.1 + 2 / 20, at the 20 fps given


def test_stamps_are_read_as_times_only_where_they_can_be(tmp_path):
    """frame_times reads a video's uneven stamps as filming times, but not stamps that do not
    increase, nor those of a video that plays far faster or slower than the fps given (a
    high-speed camera's video played at 30 frames/s counts playback); even stamps are not read."""
    from granseg.measure.pipeline import FrameTimes, frame_times
    from granseg.measure.sources import VideoFrames

    d = tmp_path / "run"
    render_frames(_map(4), seed=5, out_dir=d, **SMALL)
    video = VideoFrames(_timed_video(d, tmp_path / "v" / "run.mov", np.arange(4) / 30))
    video.times = [0.0, 1 / 30, 2 / 30, 3 / 30]
    assert frame_times(video, 30.0).seconds is None and frame_times(video, 30.0).note is None
    video.times = [0.0, 0.2, 0.3, 0.5]
    np.testing.assert_array_equal(frame_times(video, 30.0).seconds, video.times)
    played = frame_times(video, 1000.0)
    assert played.seconds is None and "playback" in played.note and played.uneven > 0.01
    video.times = [0.0, 0.2, 0.1, 0.5]
    backwards = frame_times(video, 30.0)
    assert backwards.seconds is None and "do not increase" in backwards.note
    np.testing.assert_allclose(backwards.row_seconds(4, 30.0), np.arange(4) / 30)
    np.testing.assert_allclose(frame_times(VideoFrames(video.path), 30.0).row_seconds(6, 30.0), np.arange(6) / 30)
    np.testing.assert_allclose(FrameTimes(0.1, np.array([0.0, 0.2, 0.3])).row_seconds(5, 10.0),  # cut short
                               [0.0, 0.2, 0.3, 0.4, 0.5])


def _shot_stills(d, out, shot_at, fps, names=None):
    """The frames of folder ``d`` as camera JPEGs in ``out``: frame k named ``names[k]`` (default
    frame_NNNN.jpg) and shot ``shot_at[k]`` s after 10:00 by its EXIF clock, to the second;
    experiment.json the folder's with ``fps``."""
    from PIL import Image

    out.mkdir()
    for k, (png, at) in enumerate(zip(sorted(d.glob("*.png")), shot_at, strict=True)):
        exif = Image.Exif()
        exif.get_ifd(0x8769)[36867] = f"2026:12:01 10:{int(at) // 60:02d}:{int(at) % 60:02d}"  # DateTimeOriginal
        Image.open(png).convert("RGB").save(out / (names[k] if names else f"frame_{k:04d}.jpg"), quality=95, exif=exif)
    (out / "experiment.json").write_text(json.dumps({**json.loads((d / "experiment.json").read_text()), "fps": fps}))
    return out


def test_shot_times_read_the_sub_seconds_and_need_every_file_to_carry_a_clock(tmp_path):
    from PIL import Image

    from granseg.measure.sources import shot_times

    files = []
    for k, (stamp, sub) in enumerate([("2026:12:01 23:59:59", "5"), ("2026:12:02 00:00:01", "25"),
                                      ("2026:12:02 00:00:02", None)]):
        exif = Image.Exif()
        exif.get_ifd(0x8769)[36867] = stamp
        if sub is not None:
            exif.get_ifd(0x8769)[37521] = sub
        files.append(tmp_path / f"{k}.jpg")
        Image.new("RGB", (8, 8)).save(files[-1], exif=exif)
    seconds, resolution = shot_times(files)
    np.testing.assert_allclose(seconds, [0.5, 2.25, 3.0])  # across midnight, from the first's whole second
    assert resolution == 1.0  # the coarsest: the last carries no sub-seconds
    assert shot_times(files[:2])[1] == pytest.approx(0.1)
    Image.new("RGB", (8, 8)).save(tmp_path / "plain.jpg")
    (tmp_path / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00MM\x00*garbage")
    assert shot_times([*files, tmp_path / "plain.jpg"]) is None and shot_times([tmp_path / "broken.jpg"]) is None


def test_stills_are_timed_by_their_camera_clock_where_it_disagrees(tmp_path, caplog):
    """A camera's stills carry the time each was shot (EXIF, to the second). Shot every 2 s as fps
    0.5 says, the map's times are k / fps and frame_times passes; with fps given as 0.2 (one every
    5 s, a slip), the map's times are the clock's and a warning says to check fps; with the camera's
    file numbers rolled over (IMG_9998, IMG_9999 named after IMG_0001..) frame_times fails, naming
    the frames. Stills without a clock are not checked (the other tests' PNGs)."""
    from granseg.measure import quality

    d = tmp_path / "run"
    render_frames(_map(8), seed=5, out_dir=d, **SMALL)
    every_2s = np.arange(8) * 2.0
    even = analyze(_shot_stills(d, tmp_path / "even", every_2s, 0.5), save=False, progress=False)
    (check,) = [c for c in even.quality.checks if c.name == "frame_times"]
    assert check.passed and even.quality.figures["frame_times_from_stamps"] is False
    np.testing.assert_allclose(np.diff(even.t), 2.0)
    with caplog.at_level(logging.WARNING):
        slip = analyze(_shot_stills(d, tmp_path / "slip", every_2s, 0.2), out=tmp_path / "slip.npz", progress=False)
    assert "check fps" in caplog.text and slip.quality.ok and slip.quality.figures["frame_times_from_stamps"]
    np.testing.assert_allclose(slip.t - slip.t[0], every_2s)
    assert float(np.load(tmp_path / "slip.npz")["fps"]) == pytest.approx(0.5)  # the map's rate is the clock's
    assert np.array_equal(slip.n, even.n)
    names = [f"IMG_{9998 + k:04d}.JPG" if k < 2 else f"IMG_{k - 1:04d}.JPG" for k in range(8)]
    caplog.clear()
    with pytest.warns(QualityWarning, match="frame_times"), caplog.at_level(logging.WARNING):
        rolled = analyze(_shot_stills(d, tmp_path / "rolled", every_2s, 0.5, names), save=False, progress=False)
    assert "IMG_9998.JPG was shot before IMG_0006.JPG" in caplog.text
    (check,) = [c for c in rolled.quality.checks if c.name == "frame_times"]
    assert not check.passed and check.value > 3 * quality.FRAME_TIMES_SHARE


def test_stills_timed_by_their_clock_are_cut_and_thinned_by_it(tmp_path):
    """Stills shot every 2 s with fps typed as 0.2 are timed by their camera's clock, and seconds
    given become frames by it: every_seconds = 4 analyses every second still (fps would say
    every one) and smooth_seconds = 8 averages three rows (fps: one). A negative
    t0 cuts them by that clock too: a run whose camera took two stills of the bed at rest first,
    t0 = -3 s, leaves out those two (shot at 0 and 2 s; fps would leave out one) and gives the
    run's map, its rows 1 s after the plate started. A plate start after the last still by the
    clock (18 s) is refused, though fps would put it in time."""
    d = tmp_path / "run"
    render_frames(_map(8), seed=5, out_dir=d, **SMALL)
    slip = _shot_stills(d, tmp_path / "slip", np.arange(8) * 2.0, 0.2)
    whole = analyze(slip, save=False, progress=False)
    sparse = analyze(slip, every_seconds=4.0, smooth_seconds=8.0, save=False, progress=False)
    assert sparse.every == 2 and sparse.smoothing_frames == 3 and np.array_equal(sparse.n, whole.n[::2])
    np.testing.assert_allclose(np.diff(sparse.t), 4.0)
    rest = tmp_path / "rest"
    rest.mkdir()
    pngs = sorted(d.glob("*.png"))
    for k, p in enumerate([pngs[0]] * 2 + pngs):
        shutil.copy(p, rest / f"frame_{k:04d}.png")
    exp = json.loads((d / "experiment.json").read_text())
    (rest / "experiment.json").write_text(json.dumps(exp))
    early = _shot_stills(rest, tmp_path / "early", np.arange(10) * 2.0, 0.2)
    (early / "experiment.json").write_text(json.dumps({**exp, "fps": 0.2, "t0": -3.0}))
    late = analyze(early, save=False, progress=False)
    assert late.first == 2 and late.quality.figures["frames_first"] == 2
    np.testing.assert_allclose(late.t, whole.t - whole.t[0] + 1.0)
    assert np.array_equal(late.n, whole.n) and np.array_equal(late.n_heavy, whole.n_heavy)
    (early / "experiment.json").write_text(json.dumps({**exp, "fps": 0.2, "t0": -19.0}))
    with pytest.raises(ValueError, match=r"field 't0': -19 s .* after the recording's last frame \(shot 18 s after"):
        analyze(early, save=False, progress=False)


def test_a_video_whose_header_only_estimates_its_frames_has_the_frames_it_holds(tmp_path, caplog):
    """Matroska keeps no frame count: OpenCV announces its length times its nominal rate, 16 frames
    for the 8 of a phone slowing from 30 to 10 frames/s halfway. The map has the 8 frames read, none
    of them bad, at the times of their stamps; the same file cut short keeps the frames missing as
    NaN rows, warns that it is truncated and fails bad_frames. QuickTime records its count: an even
    stream that lost its last frame, though its last frame read ends in time, is warned about too."""
    d = tmp_path / "run"
    render_frames(_map(8), seed=5, out_dir=d, **SMALL)
    even = analyze(_timed_video(d, tmp_path / "even" / "run.mov", np.arange(8) / 30), save=False, progress=False)
    uneven_at = np.r_[np.arange(4) / 30, 3 / 30 + np.arange(1, 5) / 10]
    video = _timed_video(d, tmp_path / "uneven" / "run.mkv", uneven_at)
    assert cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FRAME_COUNT) == 16  # the header's estimate
    with warnings.catch_warnings(record=True) as caught, caplog.at_level(logging.WARNING):
        warnings.simplefilter("always")
        whole = analyze(video, save=False, progress=False)
    assert caught == [] and "truncated" not in caplog.text
    assert whole.bad_frames == [] and np.array_equal(whole.n, even.n) and whole.quality.ok
    np.testing.assert_allclose(whole.t - whole.t[0], uneven_at, atol=1e-3)
    cut = tmp_path / "cut" / "run.mkv"
    cut.parent.mkdir()
    cut.write_bytes(video.read_bytes()[: int(0.6 * video.stat().st_size)])
    shutil.copy(video.parent / "experiment.json", cut.parent)
    with (pytest.warns(QualityWarning, match="bad_frames"),
          pytest.warns(BadFrameWarning, match="frame missing from the stream"), caplog.at_level(logging.WARNING)):
        short = analyze(cut, save=False, progress=False)
    assert "truncated" in caplog.text and 0 < len(short.bad_frames) < 16 and len(short.t) == 16
    assert np.all(np.diff(short.t) > 0)  # the rows past the last frame read go on at fps
    assert "bad_frames" in {c.name for c in short.quality.failed}
    lost = _timed_video(d, tmp_path / "lost" / "run.mov", np.arange(8) / 30)
    lost.write_bytes(lost.read_bytes()[:-2000])  # the last frame's image cut short
    caplog.clear()
    with (pytest.warns(QualityWarning, match="bad_frames"),
          pytest.warns(BadFrameWarning, match="frame missing from the stream"), caplog.at_level(logging.WARNING)):
        cut_mov = analyze(lost, save=False, progress=False)
    assert "truncated" in caplog.text and [n for n, _ in cut_mov.bad_frames] == [cut_mov.frame_names[7]]


@pytest.mark.parametrize("damage, message", [
    (lambda p: p.write_bytes(b""), "empty file"),
    (lambda p: p.write_bytes(p.read_bytes()[:2000]), "truncated PNG"),
    (lambda p: p.write_bytes(b"not an image at all"), "not a readable image"),
])
def test_single_bad_frame_becomes_nan_row(frames, damage, message):
    damage(sorted(frames.glob("*.png"))[2])
    # one frame of four is a quarter of the run: the bad_frames check fails too
    with pytest.warns(QualityWarning, match="bad_frames"), \
            pytest.warns(BadFrameWarning, match=f"frame_0002.png: {message}"):
        a = analyze(frames, save=False, progress=False, smooth=3)
    assert np.all(np.isnan(a.c[2])) and np.all(np.isfinite(a.c_raw[[0, 1, 3]]))
    assert [name for name, _ in a.bad_frames] == ["frame_0002.png"]


def _deeper(frames, out, suffix, shift, seed=0):
    """The frames of folder ``frames`` saved as ``suffix`` files: 16-bit with each 8-bit sample
    moved up ``shift`` bits and noise in the bits below (4: 12-bit samples in the low bits, as
    machine-vision cameras save them; 8: in the high bits), as they are where ``shift`` is 0."""
    rng = np.random.default_rng(seed)
    out.mkdir()
    for p in sorted(frames.glob("*.png")):
        img = cv2.imread(str(p))
        if shift:
            img = (img.astype(np.uint16) << shift) | rng.integers(0, 1 << shift, img.shape, dtype=np.uint16)
        cv2.imwrite(str(out / (p.stem + suffix)), img)
    shutil.copy(frames / "experiment.json", out)
    return out


@pytest.mark.parametrize("suffix, shift", [(".png", 4), (".png", 8), (".tif", 4), (".tif", 0)])
def test_frames_of_a_camera_of_more_bits_give_the_map_of_their_top_8_bits(frames, tmp_path, suffix, shift):
    """12-bit samples in 16-bit files are read at their own depth, not crushed to the 16 grey levels
    of their high byte; 16-bit samples in the high bits as before; TIFF like PNG."""
    deep = _deeper(frames, tmp_path / "deep", suffix, shift)
    if shift == 4:  # what a plain 8-bit decoding makes of them: 16 or 17 grey levels
        assert cv2.imread(str(next(deep.glob(f"*{suffix}")))).max() <= 16
    a, b = (analyze(d, save=False, progress=False) for d in (frames, deep))
    np.testing.assert_array_equal(b.n, a.n)
    np.testing.assert_array_equal(b.c_raw, a.c_raw)
    assert "sample_bits" not in a.quality.figures
    assert b.quality.figures.get("sample_bits") == {4: 12, 8: 16, 0: None}[shift]


@pytest.mark.parametrize("bits", SENSOR_BITS)
def test_samples_of_each_depth_come_back_as_their_top_8_bits(bits):
    top = np.arange(256, dtype=np.uint16)
    samples = (top << (bits - 8)) | (np.uint16((1 << (bits - 8)) - 1))  # the low bits all set
    assert sensor_bits(int(samples.max())) == bits
    np.testing.assert_array_equal(to_8bit(samples, bits), top)
    assert to_8bit(np.array([2 ** bits], np.uint16) if bits < 16 else samples[-1:], bits)[0] == 255  # clipped


def test_a_frame_of_floating_point_samples_is_a_bad_frame_named(frames):
    ok, bad = encoded = [cv2.imencode(".tif", img)[1].tobytes()
                         for img in (np.zeros((8, 8), np.uint16), np.zeros((8, 8), np.float32))]
    assert decode_still(ok, "ok.tif").shape == (8, 8, 3) and len(encoded) == 2
    with pytest.raises(BadFrame, match="bad.tif: float32 samples"):
        decode_still(bad, "bad.tif")


def _stack(frames, path, bits=8, **write):
    """The frames of folder ``frames`` as one TIFF stack at ``path`` (RGB pages, tifffile;
    ``bits`` 12: 16-bit samples in the low bits with noise below the top 8, as a camera saves
    them), experiment.json beside it."""
    import tifffile

    images = np.stack([cv2.imread(str(p))[..., ::-1] for p in sorted(frames.glob("*.png"))])
    if bits > 8:
        noise = np.random.default_rng(0).integers(0, 1 << (bits - 8), images.shape, dtype=np.uint16)
        images = (images.astype(np.uint16) << (bits - 8)) | noise
    path.parent.mkdir(exist_ok=True)
    tifffile.imwrite(path, images, photometric="rgb", **write)
    shutil.copy(frames / "experiment.json", path.parent)
    return path


@pytest.mark.parametrize("bits, compression, given", [(8, None, "file"), (12, None, "folder"), (8, "zlib", "file")])
def test_a_tiff_stack_gives_the_map_of_its_frames(frames, tmp_path, bits, compression, given):
    """A stack's pages are the recording's frames, read as stills are (a 12-bit stack at its own
    depth); the stack may be given as its file or as the folder that holds it alone."""
    from granseg.measure.sources import TiffStack, open_frames

    stack = _stack(frames, tmp_path / "stack" / "run.tif", bits, compression=compression)
    source, exp = open_frames(stack if given == "file" else stack.parent)
    assert isinstance(source, TiffStack) and exp == stack.parent / "experiment.json" and len(source) == 4
    assert source.names[2] == "run.tif#2" and source.bits == (None if bits == 8 else 12)
    a, b = (analyze(d, save=False, progress=False) for d in (frames, source.path))
    np.testing.assert_array_equal(b.n, a.n)
    np.testing.assert_array_equal(b.c_raw, a.c_raw)
    np.testing.assert_allclose(b.t, a.t)
    # every other page is every other frame; against the folder read so, since the classes' shift
    # (outline.class_shift) read from half the frames may differ from the whole run's (0.17 px from
    # 188 pairs, none taken off from 91 on an AMD EPYC machine, OpenCV 5.1) and move a sphere across
    # a row's line
    half, half_frames = (analyze(d, every=2, save=False, progress=False) for d in (stack, frames))
    assert len(half.n) == 2 and half.frame_names == ["run.tif#0", "run.tif#2"]
    np.testing.assert_array_equal(half.n, half_frames.n)
    np.testing.assert_array_equal(half.c_raw, half_frames.c_raw)


def test_an_imagej_stack_tells_its_frame_rate(frames, tmp_path, capsys):
    """ImageJ's frame interval is the stack's rate where experiment.json gives none (as a video's is)."""
    import tifffile

    from granseg.measure.sources import open_frames

    grey = np.stack([cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(frames.glob("*.png"))])
    path = tmp_path / "ij" / "run.tif"
    path.parent.mkdir()
    tifffile.imwrite(path, grey, imagej=True, metadata={"axes": "TYX", "finterval": 0.25})
    assert open_frames(path)[0].fps == 4.0
    exp = json.loads((frames / "experiment.json").read_text())
    (path.parent / "experiment.json").write_text(json.dumps({**exp, "fps": None}))
    with pytest.warns(UserWarning, match="greyscale"):
        m = analyze(path, save=False, progress=False)
    np.testing.assert_allclose(np.diff(m.t), 0.25)


def test_stacks_that_are_not_one_recording_are_refused_naming_why(frames, tmp_path, capsys):
    """A stack among other images, a stack of two channels, and one whose compression needs a
    package that is not installed are refused before any frame is analysed, saying what to do."""
    import tifffile

    mixed = tmp_path / "mixed"
    mixed.mkdir()
    cv2.imwritemulti(str(mixed / "run.tif"), [cv2.imread(str(p)) for p in sorted(frames.glob("*.png"))])
    shutil.copy(frames / "frame_0001.png", mixed / "zframe.png")
    shutil.copy(frames / "experiment.json", mixed)
    with pytest.raises(ValueError, match=r"run.tif: a TIFF stack of 4 pages among other images.*stack's file"):
        analyze(mixed, save=False, progress=False)
    assert main(["analyze", str(mixed)]) == 2 and "TIFF stack of 4 pages" in capsys.readouterr().err
    two = tmp_path / "two" / "run.tif"
    two.parent.mkdir()
    tifffile.imwrite(two, np.zeros((3, 2, 40, 50), np.uint8), imagej=True, metadata={"axes": "TCYX"})
    shutil.copy(frames / "experiment.json", two.parent)
    with pytest.raises(ValueError, match=r"run.tif: a stack of T = 3, C = 2 \(TCYX\).*one image per frame"):
        analyze(two, save=False, progress=False)
    one = _stack(frames, tmp_path / "one" / "run.tif")
    tifffile.imwrite(one, np.zeros((40, 50), np.uint8))
    with pytest.raises(ValueError, match="run.tif: a TIFF of one image, not a recording"):
        analyze(one, save=False, progress=False)
    floats = _stack(frames, tmp_path / "floats" / "run.tif")
    tifffile.imwrite(floats, np.zeros((3, 40, 50), np.float32), photometric="minisblack")
    with pytest.raises(ValueError, match="run.tif: float32 samples; save the stack as 8- or 16-bit integers"):
        analyze(floats, save=False, progress=False)
    try:
        import imagecodecs  # noqa: F401
    except ImportError:  # OpenCV writes LZW, which tifffile reads only with imagecodecs
        lzw = mixed / "run.tif"
        with pytest.raises(ValueError, match="run.tif: pages compressed with LZW.*pip install imagecodecs"):
            analyze(lzw, save=False, progress=False)


def test_frames_numbered_without_leading_zeros_are_refused_naming_two(tmp_path, capsys):
    """frame_10.png sorts before frame_2.png as text, and text order is the frames' time order: a
    folder numbered so is refused before any frame is read, by analyze and by the command line."""
    d = tmp_path / "run"
    d.mkdir()
    for i in range(1, 12):
        cv2.imwrite(str(d / f"frame_{i}.png"), np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match=r"frame_11.png before frame_2.png.*leading zeros"):
        analyze(d, save=False, progress=False)
    assert main(["analyze", str(d)]) == 2 and "leading zeros" in capsys.readouterr().err
    for i in range(1, 12):
        (d / f"frame_{i}.png").rename(d / f"frame_{i:02d}.png")
    with pytest.raises(FileNotFoundError, match="experiment.json"):  # past the names, to the next thing missing
        analyze(d, save=False, progress=False)


@pytest.mark.parametrize("stray", ["frame_0002 (1).png", "frame_0002 copy.png", "background.png"])
def test_an_image_not_named_like_the_frames_is_refused_naming_it(frames, stray, capsys):
    """A copy a file manager made of one frame, or an image that is not a frame, would sort among
    the frames and shift every later row's time by a frame: refused before any frame is read, by
    name, by analyze and by the command line."""
    shutil.copy(frames / "frame_0002.png", frames / stray)
    with pytest.raises(ValueError, match=rf"{re.escape(stray)} is not named like the other 4 frames "
                                         rf"\(frame_#.png, where # is a number\).*move it out"):
        analyze(frames, save=False, progress=False)
    assert main(["analyze", str(frames), "--no-progress"]) == 2 and stray in capsys.readouterr().err
    (frames / stray).unlink()
    assert analyze(frames, save=False, progress=False).bad_frames == []


def test_frames_without_a_numbering_keep_their_text_order(tmp_path):
    """Names that share no naming (a time-lapse tool's letters) have no numbering to break; a folder
    of them is read in text order, as DATA.md says."""
    from granseg.measure.sources import FrameDirectory

    for name in ["shot_a.png", "shot_b.png", "shot_c.png"]:
        cv2.imwrite(str(tmp_path / name), np.zeros((8, 8, 3), np.uint8))
    assert FrameDirectory(tmp_path).names == ["shot_a.png", "shot_b.png", "shot_c.png"]
    cv2.imwrite(str(tmp_path / "shot_10.png"), np.zeros((8, 8, 3), np.uint8))  # one numbered: no naming held by two
    assert len(FrameDirectory(tmp_path)) == 4


def test_hidden_files_in_a_frames_folder_are_not_frames(frames):
    """macOS leaves "._NAME.png" (its metadata, not an image) beside every file copied to an exFAT
    card; sorted first, they would be bad frames that shift every row's time."""
    whole = analyze(frames, save=False, progress=False)
    for p in sorted(frames.glob("*.png")):
        (frames / f"._{p.name}").write_bytes(b"\x00\x05\x16\x07" + bytes(4092))  # AppleDouble's magic
    again = analyze(frames, save=False, progress=False)
    assert again.bad_frames == [] and again.frame_names == whole.frame_names
    assert np.array_equal(again.t, whole.t) and np.array_equal(again.n, whole.n)


def test_frame_without_spheres_is_named(frames):
    p = sorted(frames.glob("*.png"))[1]
    cv2.imwrite(str(p), np.full((480, 400, 3), 90, np.uint8))
    with pytest.warns(QualityWarning, match="bad_frames"), \
            pytest.warns(BadFrameWarning, match="frame_0001.png: no spheres detected"):
        a = analyze(frames, save=False, progress=False)
    assert len(a.bad_frames) == 1


@pytest.mark.parametrize("edit, message", [
    (lambda e: e.pop("rho_h"), "missing field 'rho_h'"),
    (lambda e: e.update(window=[10, 20, 5, 40]), "field 'window'"),
    (lambda e: e.update(window=[-500, 0, 50, 400]), "field 'window'.*outside the image"),
    (lambda e: e.update(camera_matrix=[[1, 0], [0, 1]]), "field 'camera_matrix'"),
    (lambda e: e.update(c0=1.5), "field 'c0'"),
    (lambda e: e.pop("fps"), "field 'fps'"),
])
def test_bad_experiment_fields_are_named(frames, edit, message):
    path = frames / "experiment.json"
    exp = json.loads(path.read_text())
    edit(exp)
    path.write_text(json.dumps(exp))
    with pytest.raises(ValueError, match=message):
        analyze(frames, save=False, progress=False)


def test_missing_inputs_are_named(tmp_path, frames):
    with pytest.raises(FileNotFoundError, match="no such frames directory"):
        analyze(tmp_path / "nowhere", progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no PNG, JPEG, TIFF or BMP frames"):
        analyze(tmp_path / "empty", progress=False)
    (frames / "experiment.json").write_text("{not json")
    with pytest.raises(ValueError, match="experiment.json: not valid JSON"):
        analyze(frames, progress=False)
    (frames / "experiment.json").unlink()
    with pytest.raises(FileNotFoundError, match="experiment.json not found"):
        analyze(frames, progress=False)
    bad_video = tmp_path / "v" / "broken.mp4"
    bad_video.parent.mkdir()
    bad_video.write_bytes(b"\x00" * 1000)
    with pytest.raises(ValueError, match="broken.mp4: not a video"):
        analyze(bad_video, progress=False)


def test_existing_output_is_kept(frames):
    out = frames / "mine.npz"
    out.write_bytes(b"precious")
    with pytest.raises(OutputExistsError):
        analyze(frames, out=out, progress=False)
    assert out.read_bytes() == b"precious"


# --------------------------------------------------------------------------- camera


def _boards(tmp_path, k, dist, size):
    poses = [((0.1, -0.2, 0.05), (-3.5, -2.5, 14)), ((-0.3, 0.1, -0.1), (-5, -3, 13)),
             ((0.25, 0.3, 0.2), (-4, -4, 15)), ((-0.1, -0.35, 0.0), (-2, -2.5, 12)),
             ((0.35, 0.0, -0.2), (-6, -2, 14)), ((0.0, 0.2, 0.3), (-3, -5, 16))]
    for i, (r, t) in enumerate(poses):
        cv2.imwrite(str(tmp_path / f"board_{i}.png"), render_checkerboard(k, dist, size, r, t))


def test_checkerboards_recover_the_camera_and_straighten_lines(tmp_path):
    size = (800, 600)
    k, dist = default_camera(size, k1=-0.25)
    _boards(tmp_path, k, dist, size)
    res = calibrate_camera(tmp_path)
    assert res["reprojection_error_px"] < 0.5
    assert np.allclose(np.array(res["camera_matrix"])[[0, 1], [0, 1]], k[[0, 1], [0, 1]], rtol=0.02)
    # straight lines: a board seen through the lens has curved rows; undistorted, straight
    img = render_checkerboard(k, dist, size, (0.05, 0.05, 0.0), (-5.0, -3.5, 11.5))
    und = Undistorter(res["camera_matrix"], res["dist_coeffs"], size, (0, 0, *size))(img)
    assert _row_curvature(find_checkerboard(img, (9, 6))) > 1.0
    assert _row_curvature(find_checkerboard(und, (9, 6))) < 0.3


def test_checkerboards_from_a_12_bit_camera_are_read_at_their_depth(tmp_path):
    """Boards shot at a quarter of a 12-bit camera's range (samples up to 1020 in 16-bit files),
    which a plain 8-bit decoding leaves 4 grey levels deep, calibrate as their 8-bit originals do
    (read so, the corners moved: reprojection error 0.116 -> 0.142 px)."""
    size = (640, 480)
    k, dist = default_camera(size, k1=-0.25)
    _boards(tmp_path, k, dist, size)
    plain = calibrate_camera(tmp_path)
    for p in tmp_path.glob("board_*.png"):
        cv2.imwrite(str(p), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.uint16) << 2)
    deep = calibrate_camera(tmp_path)
    assert deep["images_used"] == plain["images_used"]
    assert deep["reprojection_error_px"] == pytest.approx(plain["reprojection_error_px"], rel=1e-6)
    np.testing.assert_allclose(deep["camera_matrix"], plain["camera_matrix"], rtol=1e-6)
    np.testing.assert_allclose(deep["dist_coeffs"], plain["dist_coeffs"], rtol=1e-6, atol=1e-9)


def test_the_undistortion_tables_send_each_pixel_through_the_lens():
    """A crop's tables (past the image's edge too) say where the lens puts each undistorted pixel:
    the pixel's ray projected through the camera matrix and distortion, as cv2.projectPoints does."""
    size = (640, 480)
    k, _ = default_camera(size, k1=-0.3)
    dist = np.array([-0.32, 0.11, 0.0005, -0.0004, -0.015])
    x0, y0, x1, y1 = (-20, 30, 500, 470)
    und = Undistorter(k, dist, size, (x0, y0, x1, y1))
    xs, ys = np.meshgrid(np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float))
    rays = np.stack([(xs - k[0, 2]) / k[0, 0], (ys - k[1, 2]) / k[1, 1], np.ones_like(xs)], -1)
    seen, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, dist)
    np.testing.assert_allclose(und._source.reshape(-1, 2), seen.reshape(-1, 2), atol=1e-3)
    assert und.inside_image((100, 100, 400, 400))
    wide = Undistorter(k, dist, size, (-400, 0, 100, 100))  # far past the left edge, even through a barrel
    assert wide._source[0, 0, 0] < 0 and not wide.inside_image((-400, 0, 100, 100))


def _row_curvature(corners) -> float:
    """Largest distance [px] of a board corner from the straight line through its row."""
    rows = corners.reshape(6, 9, 2)
    worst = 0.0
    for row in rows:
        centred = row - row.mean(axis=0)
        _, _, vt = np.linalg.svd(centred)
        worst = max(worst, float(np.abs(centred @ vt[1]).max()))
    return worst


def test_calibrate_camera_cli(tmp_path, capsys):
    size = (640, 480)
    k, dist = default_camera(size)
    _boards(tmp_path, k, dist, size)
    assert main(["calibrate-camera", str(tmp_path), "--pattern", "9x6"]) == 0
    assert "reprojection error" in capsys.readouterr().out
    saved = json.loads((tmp_path / "camera.json").read_text())
    assert len(saved["camera_matrix"]) == 3 and len(saved["dist_coeffs"]) == 5
    with pytest.raises(ValueError, match="no checkerboard images"):
        (tmp_path / "none").mkdir()
        calibrate_camera(tmp_path / "none")
