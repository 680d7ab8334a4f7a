"""The camera's exposure measured on the bed and taken off (granseg.measure.exposure)."""

import numpy as np
import pytest

from granseg.measure.exposure import (
    DRIFT_LIMIT,
    SURVEY_FRAMES,
    Exposure,
    bed_level,
    survey,
    survey_indices,
)

ROWS = (0, 200)


def _bed(seed: int, gain: float = 1.0, size=(200, 300)) -> np.ndarray:
    """Dark gaps, two grey materials and bright highlights at random, taken at ``gain`` (clipped at
    255): (h, w, 3) uint8."""
    rng = np.random.default_rng(seed)
    kinds = rng.choice([20.0, 90.0, 160.0, 230.0], p=[0.2, 0.4, 0.3, 0.1], size=size)
    grey = np.clip(gain * (kinds + rng.normal(0, 6, size)), 0, 255)
    return np.repeat(grey[..., None], 3, axis=2).astype(np.uint8)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_level_counted_by_grey_level_is_the_sorted_middle_half(seed):
    """The level from the 256 levels' counts is the mean of the middle half by rank, as sorting
    gives it, with a third of the bed clipped at 255 and on an odd number of pixels."""
    bed = _bed(seed, gain=1.6, size=(101, 33))
    grey = np.sort(bed[..., 0].ravel())
    lo, hi = grey.size // 4, (3 * grey.size) // 4
    assert bed_level(bed, (0, 101)) == pytest.approx(grey[lo:hi].mean(), rel=1e-12)


def test_the_level_is_the_same_for_the_same_bed_rearranged():
    """The window holds the same materials in every frame, only moved: the level does not move."""
    assert bed_level(_bed(1), ROWS) == pytest.approx(bed_level(_bed(2), ROWS), rel=0.01)


@pytest.mark.parametrize("gain", [0.5, 0.7, 1.3, 1.6])
def test_a_frame_at_another_gain_is_brought_back_and_clipped_as_the_brightest(gain):
    """Every frame, the first included, ends clipped where the brightest frame clipped: the first
    frame's look and a brightened frame's agree once both are matched."""
    first, frame = _bed(1), _bed(2, gain)
    ex = survey([bed_level(frame, ROWS)], bed_level(first, ROWS))
    assert ex.most_gain == pytest.approx(max(1.0, gain), rel=0.03)
    back, seen = ex.match(frame, ROWS)
    assert seen == pytest.approx(gain, rel=0.03)
    ref, _ = ex.match(first, ROWS)
    assert bed_level(back, ROWS) == pytest.approx(bed_level(ref, ROWS), rel=0.03)
    # the brightest material: clipped alike in both (it was at 255 in the brightened frame)
    assert np.percentile(back, 95) == pytest.approx(np.percentile(ref, 95), abs=3)
    if gain > 1:
        assert ref.max() == back.max() == ex.clip < 255


def test_a_steady_camera_leaves_the_frames_as_they_were():
    """A level that strays by less than DRIFT_LIMIT (glass mixing with POM reads so) changes nothing."""
    frame, level = _bed(2), bed_level(_bed(2), ROWS)
    ex = survey([1.15 * level, 0.85 * level], level)
    assert (ex.least_gain, ex.most_gain) == pytest.approx((0.85, 1.15)) and 0.15 < DRIFT_LIMIT
    assert not ex.drifting and ex.clip == 255
    same, seen = ex.match(frame, ROWS)
    assert same is frame and seen == pytest.approx(1.0)
    unmatched, seen = Exposure(0.0).match(frame, ROWS)  # no reference level (a black first frame)
    assert unmatched is frame and seen == 1.0


def test_the_survey_spreads_over_the_run_after_the_first_readable_frame():
    """The first frame is the reference, read once; the survey spreads from it to the last."""
    picked = survey_indices(500, 3)
    assert min(picked) > 3 and max(picked) == 499 and len(picked) == SURVEY_FRAMES - 1
    assert survey_indices(5, 0) == {1, 2, 3, 4}
    assert survey_indices(1, 0) == set()


def test_the_surveyed_frames_come_in_order_and_the_unreadable_are_left_out(tmp_path):
    """Decoded in threads, the survey's frames still come in index order, each its own image; an
    empty and a truncated file are skipped, not raised."""
    import cv2

    from granseg.measure.sources import FrameDirectory

    for i in range(7):
        cv2.imwrite(str(tmp_path / f"frame_{i:04d}.png"), np.full((8, 6, 3), 10 * i, np.uint8))
    (tmp_path / "frame_0003.png").write_bytes(b"")
    data = (tmp_path / "frame_0005.png").read_bytes()
    (tmp_path / "frame_0005.png").write_bytes(data[: len(data) // 2])
    got = list(FrameDirectory(tmp_path).some({6, 0, 3, 5, 2, 4}, workers=2))
    assert [i for i, _ in got] == [0, 2, 4, 6]
    assert [int(img[0, 0, 0]) for _, img in got] == [0, 20, 40, 60]


@pytest.mark.parametrize("codec", ["FFV1", "mp4v", "h264"])
def test_the_survey_seeks_far_frames_of_a_video_and_lands_on_them(tmp_path, monkeypatch, codec):
    """Frames of a video further apart than SEEK_FRAMES are sought, not decoded one by one, and
    each is the frame asked for, as grabbing all between gives it: in a lossless stream of key
    frames, in MPEG-4 and in H.264 with a key frame every 15 (OpenCV decodes forward from the key
    frame before); also from a later first frame and with a stride (``keep``), and so are the
    analysis's frames at a stride longer than SEEK_FRAMES."""
    import cv2

    from granseg.measure import sources
    from granseg.synth.frames import _encode

    def drawn(k: int) -> np.ndarray:  # frame k: a bright block in band k // 64, column k % 64
        img = np.zeros((256, 256, 3), np.uint8)
        img[64 * (k // 64):64 * (k // 64) + 64, 4 * (k % 64):4 * (k % 64) + 4] = 255
        return img

    def shown(img: np.ndarray) -> int:  # which k a decoded frame shows
        blocks = img[..., 0].reshape(4, 64, 64, 4).mean(axis=(1, 3))
        band, column = np.unravel_index(np.argmax(blocks), blocks.shape)
        return int(64 * band + column)

    path = tmp_path / "frames.avi"
    if codec == "h264":  # a key frame every 15, as a GoPro's
        pytest.importorskip("av")
        path = path.with_suffix(".mp4")
        _encode([drawn(k) for k in range(240)], path, "h264", None)
    else:
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), 30.0, (256, 256))
        for k in range(240):
            writer.write(drawn(k))
        writer.release()
    seeks = []
    capture = cv2.VideoCapture

    class Counted:  # a capture that counts its seeks (a subclass of OpenCV's crashes when collected)
        def __init__(self, *args):
            self.cap = capture(*args)

        def set(self, prop, value):
            seeks.append(value)
            return self.cap.set(prop, value)

        def __getattr__(self, name):
            return getattr(self.cap, name)

    video = sources.VideoFrames(path)
    for every, first in ((1, 0), (3, 5)):
        video.keep(every, first)
        wanted = survey_indices(len(video), 0)
        read = dict(video.some(wanted))
        assert not seeks
        monkeypatch.setattr(sources, "SEEK_FRAMES", 4)
        monkeypatch.setattr(cv2, "VideoCapture", Counted)
        sought = dict(video.some(wanted))
        monkeypatch.undo()
        assert len(seeks) == len(wanted)  # every one sought: they lie 9 or more frames apart
        seeks.clear()
        assert sorted(read) == sorted(sought) == sorted(wanted)
        # the analysis's pass, at a stride longer than SEEK_FRAMES, seeks every frame (the first
        # too: it is 5 frames in)
        grabbed = [shown(img) for _, img in video.frames()]
        assert grabbed == list(range(first, 240, every)) and not seeks
        monkeypatch.setattr(sources, "SEEK_FRAMES", max(every - 2, 0))
        monkeypatch.setattr(cv2, "VideoCapture", Counted)
        assert [shown(img) for _, img in video.frames()] == grabbed
        monkeypatch.undo()
        if every > 1:  # each kept frame sought, then one past the end, where the stream stops
            assert seeks[:len(grabbed)] == grabbed and len(seeks) <= len(grabbed) + 1
            assert len(grabbed) <= video.sought <= len(seeks)
        else:
            assert not seeks and not video.sought
        seeks.clear()
        for i in wanted:
            target = first + i * every
            assert shown(read[i]) == target  # grabbed: the frame itself
            assert shown(sought[i]) == target


class _TimedStream:
    """A stand-in for a capture on a clock of its own: a grab takes 1 s, a seek ``seek`` s."""

    def __init__(self, seek: float):
        self.now, self.seek, self.calls = 0.0, seek, []

    def clock(self) -> float:
        return self.now

    def grab(self) -> bool:
        self.now += 1.0
        self.calls.append("grab")
        return True

    def set(self, prop, value) -> bool:
        self.now += self.seek
        self.calls.append("seek")
        return True


@pytest.mark.parametrize(("seek", "gap", "later"), [(20.0, 60, "seek"), (165.0, 60, "grab"), (20.0, 32, "grab"),
                                                    (165.0, 301, "seek"), (59.0, 60, "seek"), (61.0, 60, "grab")])
def test_frames_between_are_sought_or_grabbed_by_what_each_has_cost_in_this_stream(seek, gap, later):
    """Between TRY_SEEK_FRAMES and SEEK_FRAMES frames apart a video's frames are sought where its
    seeks have cost less than grabbing the frames between, after a grab and TRIAL_SEEKS seeks to
    learn both costs: a stream with key frames close together (a seek as dear as 20 grabs) is
    sought at a stride of 60, one with them far apart (165) is grabbed through; nearer frames are
    always grabbed, further ones always sought. A second pass through the stream uses what the
    first learned."""
    from granseg.measure import sources

    stream = _TimedStream(seek)
    mover = sources._Mover(stream.clock)
    made = []
    for k in range(8):
        before = len(stream.calls)
        assert mover.to(stream, k * (gap + 1), (k + 1) * (gap + 1) - 1)  # each frame read, then the gap to the next
        made.append("seek" if "seek" in stream.calls[before:] else "grab")
    if sources.TRY_SEEK_FRAMES < gap <= sources.SEEK_FRAMES:
        assert made[:1 + sources.TRIAL_SEEKS] == ["grab"] + ["seek"] * sources.TRIAL_SEEKS  # learning
        assert made[1 + sources.TRIAL_SEEKS:] == [later] * (7 - sources.TRIAL_SEEKS)
    else:
        assert made == [later] * 8
    assert mover.grabs == stream.calls.count("grab")
    assert mover.grab_seconds == pytest.approx(mover.grabs) and mover.seek_seconds == pytest.approx(seek * mover.seeks)
    again = _TimedStream(seek)  # the next pass through the stream (the analysis's, after the survey's) learns nothing anew
    for k in range(4):
        assert mover.to(again, k * (gap + 1), (k + 1) * (gap + 1) - 1)
    assert again.calls == ([later] if later == "seek" else ["grab"] * gap) * 4
