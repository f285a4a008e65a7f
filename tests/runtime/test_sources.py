"""Sources of ``run``: Livox SDK1 packets, image folders with times.csv, video files, prefetching, and time pairing of
frames with clouds (the recorded cloud sources themselves are tested in tests/io/test_cloud_sources.py)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io import Cloud, write_pcd
from radarcal.io.cloud_sources import FolderCloudSource
from radarcal.runtime.sources import CameraFrame, image_folder_frames, merge_by_time, open_clouds


def test_folders_times_and_pairing(tmp_path):
    import cv2

    (tmp_path / "img").mkdir()
    for i in range(4):
        cv2.imwrite(str(tmp_path / "img" / f"{i:06d}.png"), np.full((8, 8, 3), i, np.uint8))
    (tmp_path / "img" / "times.csv").write_text("file,t\n" + "".join(f"{i:06d}.png,{i / 30:.6f}\n" for i in range(4)))
    frames = list(image_folder_frames(tmp_path / "img"))
    assert [f.name for f in frames] == [f"{i:06d}.png" for i in range(4)] and frames[2].load()[0, 0, 0] == 2
    (tmp_path / "cl").mkdir()
    for k, stem in enumerate(["1700000000.000000", "1700000000.050000"]):
        write_pcd(tmp_path / "cl" / f"{stem}.pcd", np.full((3, 3), k, np.float32))
    src = FolderCloudSource(tmp_path / "cl")
    clouds = list(src)
    assert [c.t for c in clouds] == pytest.approx([1700000000.0, 1700000000.05])  # file-name stamps stay absolute
    with pytest.raises(InputError, match="clocks differ"):  # frames from 0, clouds at 1.7e9 s: refused, not silently unpaired
        list(merge_by_time(iter(frames), src))
    pairs = list(merge_by_time(iter(frames), src, "first"))
    assert [len(b) for _, b in pairs] == [1, 0, 1, 0]  # cloud at 0.05 waits for the frame at 0.0667
    assert [c.t for _, b in pairs for c in b] == pytest.approx([0.0, 0.05])
    assert [c.t for c in src] == pytest.approx([1700000000.0, 1700000000.05])  # the source's stamps are untouched
    pairs = list(merge_by_time(iter(frames), src, -1700000000.0 + 0.01))
    assert [len(b) for _, b in pairs] == [0, 1, 1, 0]  # clouds at 0.01 and 0.06 on the camera clock
    one = Cloud(np.zeros((1, 3), np.float32), t=0.01)
    pairs = list(merge_by_time(iter(frames), [one], cloud_offset_s=0.05))
    assert [len(b) for _, b in pairs] == [0, 0, 1, 0] and one.t == 0.01 and pairs[2][1][0].t == pytest.approx(0.06)
    with pytest.raises(InputError, match="cloud-time-offset"):
        list(merge_by_time(iter(frames), [one], cloud_offset_s="later"))
    (tmp_path / "img" / "times.csv").write_text("file,t\n000000.png,abc\n")
    with pytest.raises(InputError, match="times.csv"):
        list(image_folder_frames(tmp_path / "img"))
    with pytest.raises(InputError):
        open_clouds(str(tmp_path / "missing"))


def test_live_source_is_polled_and_shifted():
    """Anything with a non-blocking poll() is live: what arrived since the last frame pairs with this one."""
    frames = [CameraFrame(0.1 * i, str(i), lambda: None, i) for i in range(3)]

    class Live:
        def __init__(self):
            self.queue = [[Cloud(np.zeros((2, 3), np.float32), t=5.0)], [], [Cloud(np.zeros((1, 3), np.float32), t=5.2)]]

        def poll(self):
            return self.queue.pop(0)

    pairs = list(merge_by_time(iter(frames), Live(), "first"))
    assert [len(b) for _, b in pairs] == [1, 0, 1]
    assert [c.t for _, b in pairs for c in b] == pytest.approx([0.0, 0.2])


def test_video_file_frames(tmp_path):
    import cv2

    from radarcal.runtime.sources import open_camera

    path = tmp_path / "v.mp4"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (64, 48))
    for i in range(10):
        w.write(np.full((48, 64, 3), 20 * i, np.uint8))
    w.release()
    frames = list(open_camera(str(path)))
    assert len(frames) == 10
    assert [f.t for f in frames] == pytest.approx([i / 25 for i in range(10)], abs=1e-3)
    assert abs(int(frames[5].load().mean()) - 100) < 6
    with pytest.raises(InputError):
        list(open_camera(str(tmp_path / "missing.mp4")))


def test_prefetch_frames_keeps_order_and_errors(tmp_path):
    import cv2

    from radarcal.runtime.sources import prefetch_frames

    (tmp_path / "img").mkdir()
    for i in range(6):
        cv2.imwrite(str(tmp_path / "img" / f"{i:06d}.png"), np.full((8, 8, 3), i, np.uint8))
    (tmp_path / "img" / "000003.png").write_bytes(b"bad")
    got = list(prefetch_frames(image_folder_frames(tmp_path / "img"), depth=2))
    assert [f.name for f in got] == [f"{i:06d}.png" for i in range(6)]
    assert got[5].load()[0, 0, 0] == 5
    with pytest.raises(InputError):
        got[3].load()

    def slow_live():
        for i in range(20):
            time.sleep(0.005)
            yield CameraFrame(i * 0.005, str(i), lambda i=i: np.full((2, 2), i), i)

    out = []
    for f in prefetch_frames(slow_live(), latest_only=True):
        time.sleep(0.03)  # a slow consumer only ever sees the newest frames
        out.append(int(f.name))
    assert out[-1] == 19 and len(out) < 20 and out == sorted(out)
