"""Video files: written by VideoFileWriter, read back by VideoFile (frame count, container times, pixels), and the
three readers built on it: run's video camera, --realtime-video pacing, the recorder's VideoFileFrames."""

from __future__ import annotations

import time

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io.camera_live import VideoFileFrames
from radarcal.io.video import VideoFile, VideoFileWriter
from radarcal.runtime.replay import paced_video
from radarcal.runtime.sources import video_frames

N, FPS, H, W = 12, 25.0, 48, 64


def _frame(i: int) -> np.ndarray:
    img = np.zeros((H, W, 3), np.uint8)
    img[:, : 4 * (i + 1)] = 200  # a bar that grows one step per frame: frame order is visible in the pixels
    return img


@pytest.fixture
def video(tmp_path):
    path = tmp_path / "v.avi"
    w = VideoFileWriter(path, FPS)
    for i in range(N):
        w.write(_frame(i))
    w.close()
    return path


def _bar(img: np.ndarray) -> int:
    return int((img[H // 2, :, 1] > 100).sum())


def test_written_video_reads_back_in_order_with_container_times(video):
    v = VideoFile(str(video))
    assert v.fps == pytest.approx(FPS)
    got = list(v.frames())
    assert len(got) == N
    t = np.array([g[0] for g in got])
    assert np.allclose(t, np.arange(N) / FPS, atol=1e-3)  # MJPG in AVI: position i / fps
    assert all(img.shape == (H, W, 3) for _, img in got)
    assert [_bar(img) for _, img in got] == [4 * (i + 1) for i in range(N)]  # MJPG blurs edges by < 1 px at this contrast


def test_video_camera_frames_of_run(video):
    frames = list(video_frames(str(video)))
    assert [f.name for f in frames] == [f"{i:06d}" for i in range(N)] and [f.index for f in frames] == list(range(N))
    assert np.allclose([f.t for f in frames], np.arange(N) / FPS, atol=1e-3)
    assert _bar(frames[5].load()) == 24


def test_paced_video_delivers_at_the_frame_rate(video):
    t0 = time.monotonic()
    frames = list(paced_video(str(video)))
    wall = time.monotonic() - t0
    assert len(frames) == N and wall >= (N - 1) / FPS - 0.01
    gaps = np.diff([f.t for f in frames])
    assert np.median(gaps) == pytest.approx(1 / FPS, abs=0.01)  # host-clock receive times one frame period apart


def test_video_file_frames_of_the_recorder(video):
    src = VideoFileFrames(str(video))
    got = list(src)
    src.release()
    assert [n for _, n, _ in got] == [f"{i:06d}" for i in range(N)] and _bar(got[-1][2]) == 4 * N


def test_unreadable_videos_name_the_file(tmp_path):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video at all")
    with pytest.raises(InputError, match="cannot open video source") as e:
        next(video_frames(str(bad)))
    assert e.value.source == str(bad)
    with pytest.raises(InputError, match="cannot open video"):
        next(paced_video(str(bad)))
    with pytest.raises(InputError, match="video file not found"):
        VideoFileFrames(str(tmp_path / "missing.mp4"))
