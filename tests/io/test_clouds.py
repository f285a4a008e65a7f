"""Point-cloud readers against open3d's writers and the real data sets."""

from __future__ import annotations

import time

import numpy as np
import pytest

import radarcal.io.clouds as clouds
from radarcal.errors import InputError
from radarcal.io import read_cloud, write_pcd

o3d = pytest.importorskip("open3d", reason="open3d is needed to write reference clouds")


def _cloud(n=5000, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-60, 60, (n, 3)).astype(np.float32)
    inten = rng.integers(0, 256, n).astype(np.float32)
    return pts, inten


def _o3d_t_write(path, pts, inten=None, compressed=False, ascii=False, extra=None):
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(pts)
    if inten is not None:
        pc.point.intensity = o3d.core.Tensor(inten[:, None])
    for k, v in (extra or {}).items():
        pc.point[k] = o3d.core.Tensor(v[:, None])
    assert o3d.t.io.write_point_cloud(str(path), pc, write_ascii=ascii, compressed=compressed)
    return path


def test_write_pcd_round_trip_and_open3d_reads_it(tmp_path):
    pts, inten = _cloud()
    write_pcd(tmp_path / "a.pcd", pts, inten)
    c = read_cloud(tmp_path / "a.pcd")
    assert c.points.dtype == np.float32 and c.points.shape == pts.shape
    assert np.array_equal(c.points, pts) and np.array_equal(c.intensity, inten)
    ref = o3d.t.io.read_point_cloud(str(tmp_path / "a.pcd"))
    assert np.array_equal(ref.point.positions.numpy(), pts)
    assert np.array_equal(ref.point.intensity.numpy().ravel(), inten)
    write_pcd(tmp_path / "b.pcd", pts)
    c = read_cloud(tmp_path / "b.pcd")
    assert c.intensity is None and np.array_equal(c.points, pts)


def test_pcd_ascii_written_by_open3d(tmp_path):
    pts, inten = _cloud(800)
    pts = np.round(pts, 3)  # ascii keeps what it prints
    _o3d_t_write(tmp_path / "a.pcd", pts, inten, ascii=True)
    assert b"DATA ascii" in (tmp_path / "a.pcd").read_bytes()[:400]
    c = read_cloud(tmp_path / "a.pcd")
    np.testing.assert_allclose(c.points, pts, atol=1e-6)
    assert np.array_equal(c.intensity, inten)


def test_pcd_ascii_by_hand_with_count_and_padding(tmp_path):
    text = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb normal_x _ intensity\nSIZE 4 4 4 4 4 1 4\nTYPE F F F F F U F\n"
        "COUNT 1 1 1 1 1 1 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n"
        "1.5 2.5 3.5 0 0.1 0 10\nnan nan nan 0 0 0 20\n-1 -2 -3 0 0.2 0 30\n"
    )
    (tmp_path / "h.pcd").write_text(text)
    c = read_cloud(tmp_path / "h.pcd")
    np.testing.assert_array_equal(c.points, [[1.5, 2.5, 3.5], [-1, -2, -3]])  # NaN row dropped
    np.testing.assert_array_equal(c.intensity, [10, 30])


def test_pcd_binary_with_mixed_types(tmp_path):
    n = 100
    rng = np.random.default_rng(3)
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("ring", "<u2"), ("t", "<f8")])
    arr = np.zeros(n, dt)
    for k in "xyz":
        arr[k] = rng.normal(size=n)
    arr["intensity"] = rng.integers(0, 255, n)
    header = ("VERSION 0.7\nFIELDS x y z intensity ring t\nSIZE 4 4 4 1 2 8\nTYPE F F F U U F\nCOUNT 1 1 1 1 1 1\n"
              f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n")
    (tmp_path / "m.pcd").write_bytes(header.encode() + arr.tobytes())
    c = read_cloud(tmp_path / "m.pcd")
    np.testing.assert_array_equal(c.points, np.stack([arr["x"], arr["y"], arr["z"]], 1))
    np.testing.assert_array_equal(c.intensity, arr["intensity"].astype(np.float32))


def test_pcd_binary_compressed_written_by_open3d(tmp_path):
    pts, inten = _cloud(20000, seed=1)
    pts[::7] = np.round(pts[::7])  # some repetition so LZF emits back references too
    inten[:5000] = 0  # and a long run (overlapping back references)
    ring = (np.arange(len(pts)) % 16).astype(np.uint16)
    _o3d_t_write(tmp_path / "c.pcd", pts, inten, compressed=True, extra={"ring": ring})
    assert b"DATA binary_compressed" in (tmp_path / "c.pcd").read_bytes()[:400]
    c = read_cloud(tmp_path / "c.pcd")
    assert np.array_equal(c.points, pts)
    assert np.array_equal(c.intensity, inten)
    assert np.array_equal(c.ring, ring.astype(np.int32))


def test_read_cloud_never_imports_open3d(tmp_path):
    """The runtime's hot path: a large binary_compressed PCD is decoded without importing open3d (~1 s)."""
    import subprocess
    import sys

    pts, inten = _cloud(150_000, seed=2)
    _o3d_t_write(tmp_path / "big.pcd", pts, inten, compressed=True)
    code = ("import sys; from radarcal.io import read_cloud; c = read_cloud(sys.argv[1]); "
            "assert 'open3d' not in sys.modules, 'open3d imported'; print(len(c))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "big.pcd")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "150000"


def test_lzf_decoder_against_known_stream(tmp_path):
    """A hand-assembled LZF stream: literal 'abc', back reference (len 3, offset 3) -> 'abc', then an
    overlapping back reference (len 8, offset 1) that repeats 'c'."""
    stream = bytes([2]) + b"abc" + bytes([(1 << 5) | 0, 2]) + bytes([(6 << 5) | 0, 0])
    assert clouds._lzf_decompress(stream, 14) == b"abcabc" + b"c" * 8
    assert clouds._lzf_decompress(stream, 15) is None  # decodes to 14 bytes, not the 15 the header claims
    assert clouds._lzf_decompress(stream, 13) is None
    assert clouds._lzf_decompress(bytes([(1 << 5) | 0, 9]), 3) is None  # reference before the start
    # through the reader: a corrupt body is one InputError naming the file
    n = 4
    header = (f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA binary_compressed\n").encode()
    body = np.array([3, 48], "<u4").tobytes() + bytes([(1 << 5) | 0, 9, 0])
    (tmp_path / "bad.pcd").write_bytes(header + body)
    with pytest.raises(InputError, match="bad.pcd.*corrupt"):
        read_cloud(tmp_path / "bad.pcd")


def test_real_mlcc_width0_header(shared):
    d = shared("mlcc_livox_mid100_scene2")
    expected = {"lidar1_pose10.pcd": 240887, "lidar2_pose12.pcd": 246427, "lidar2_pose13.pcd": 253311}  # SOURCE.md
    for name, n in expected.items():
        path = d / "clouds" / name
        header = path.read_bytes()[:400]
        assert b"WIDTH 0" in header and f"POINTS {n}".encode() in header
        c = read_cloud(path)
        assert len(c) == n and c.points.shape == (n, 3) and c.intensity.shape == (n,)
        assert np.all(c.intensity == 0)  # SOURCE.md: intensity is 0 for every point
        ref = o3d.io.read_point_cloud(str(path))
        assert np.array_equal(c.points, np.asarray(ref.points, dtype=np.float32))
    c = read_cloud(d / "clouds" / "lidar1_pose10.pcd")  # SOURCE.md ranges: x 1.10..72.79 y -19.61..11.55 z -0.51..13.79
    np.testing.assert_allclose(c.points.min(0), [1.10, -19.61, -0.51], atol=0.006)
    np.testing.assert_allclose(c.points.max(0), [72.79, 11.55, 13.79], atol=0.006)


def test_ply_binary_and_ascii_written_by_open3d(tmp_path):
    pts, _ = _cloud(3000, seed=2)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    assert o3d.io.write_point_cloud(str(tmp_path / "b.ply"), pcd, write_ascii=False)
    assert o3d.io.write_point_cloud(str(tmp_path / "a.ply"), pcd, write_ascii=True)
    assert b"binary_little_endian" in (tmp_path / "b.ply").read_bytes()[:200]
    assert b"format ascii" in (tmp_path / "a.ply").read_bytes()[:200]
    b = read_cloud(tmp_path / "b.ply")
    np.testing.assert_array_equal(b.points, pts)  # float64 on disk, exact after float32
    a = read_cloud(tmp_path / "a.ply")
    np.testing.assert_allclose(a.points, pts, atol=1e-4)  # open3d writes ascii PLY with limited digits
    # tensor API: float32 positions plus an intensity attribute
    _o3d_t_write(tmp_path / "t.ply", pts, np.arange(len(pts), dtype=np.float32))
    t = read_cloud(tmp_path / "t.ply")
    assert np.array_equal(t.points, pts) and np.array_equal(t.intensity, np.arange(len(pts), dtype=np.float32))


def test_ply_big_endian_by_hand(tmp_path):
    pts = np.array([[1.0, 2.0, 3.0], [4.0, -5.0, 6.5]], ">f4")
    head = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    (tmp_path / "be.ply").write_bytes(head + pts.tobytes())
    np.testing.assert_array_equal(read_cloud(tmp_path / "be.ply").points, pts.astype(np.float32))


def test_kitti_bin(shared):
    path = shared("kitti_000008") / "000008.bin"
    c = read_cloud(path)
    assert len(c) == 17238  # SOURCE.md
    raw = np.fromfile(path, "<f4").reshape(-1, 4)
    assert np.array_equal(c.points, raw[:, :3]) and np.array_equal(c.intensity, raw[:, 3])
    np.testing.assert_allclose(c.points.min(0), [2.89, -26.42, -3.61], atol=0.006)
    np.testing.assert_allclose(c.points.max(0), [76.83, 10.28, 2.87], atol=0.006)
    assert 0 <= c.intensity.min() and c.intensity.max() <= 0.99 + 1e-6


def test_npy(tmp_path):
    pts, inten = _cloud(50)
    np.save(tmp_path / "a.npy", np.c_[pts, inten].astype(np.float64))
    c = read_cloud(tmp_path / "a.npy")
    assert np.array_equal(c.points, pts) and np.array_equal(c.intensity, inten)
    np.save(tmp_path / "b.npy", pts)
    assert read_cloud(tmp_path / "b.npy").intensity is None


def _garbage_cases(tmp_path):
    pts, inten = _cloud(2000)
    write_pcd(tmp_path / "ok.pcd", pts, inten)
    good = (tmp_path / "ok.pcd").read_bytes()
    _o3d_t_write(tmp_path / "okc.pcd", pts, inten, compressed=True)
    goodc = (tmp_path / "okc.pcd").read_bytes()
    cut = goodc.index(b"binary_compressed\n") + 18
    pcd_ply = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    o3d.io.write_point_cloud(str(tmp_path / "ok.ply"), pcd_ply)
    goodply = (tmp_path / "ok.ply").read_bytes()
    corrupt = bytearray(goodc)
    corrupt[cut + 8] = 0xFF  # first token: a back reference before the start of the output
    return {
        "truncated.pcd": good[: len(good) - 1000],
        "truncated_compressed.pcd": goodc[: len(goodc) - 500],
        "corrupt_compressed.pcd": bytes(corrupt),
        "header_only.pcd": good[: good.index(b"DATA")],
        "garbage.pcd": b"\x00\x01garbage" * 50,
        "no_xyz.pcd": b"VERSION 0.7\nFIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n",
        "ascii_words.pcd": b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\none two three\n",
        "ascii_short.pcd": b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n1 2 3\n",
        "bad_type.pcd": b"VERSION 0.7\nFIELDS x y z\nSIZE 3 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n" + b"\0" * 11,
        "bad_points.pcd": b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS many\nDATA binary\n" + b"\0" * 12,
        "truncated.ply": goodply[: len(goodply) - 100],
        "garbage.ply": b"\x89PNG\r\n\x1a\n" + b"\x00" * 100,
        "header_only.ply": goodply[: goodply.index(b"end_header")],
        "ascii_short.ply": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
        "ascii_words.ply": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\na b c\n",
        "truncated.bin": np.zeros(4 * 10, "<f4").tobytes()[:-6],
        "empty.bin": b"",
        "garbage.npy": b"\x93NUMPY garbage",
        "wrong_shape.npy": None,
        "pickled.npy": None,
        "cloud.xyz": b"1 2 3\n",
    }


def test_truncated_and_garbage_files_name_the_file(tmp_path):
    cases = _garbage_cases(tmp_path)
    np.save(tmp_path / "wrong_shape.npy", np.zeros((10, 2)))
    np.save(tmp_path / "pickled.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    for name, data in cases.items():
        path = tmp_path / name
        if data is not None:
            path.write_bytes(data)
        with pytest.raises(InputError) as e:
            read_cloud(path)
        assert e.value.source == str(path), name
        assert e.value.message and "\n" not in e.value.message, name
    with pytest.raises(InputError, match="point cloud not found"):
        read_cloud(tmp_path / "missing.pcd")


def test_one_million_point_compressed_read_time(tmp_path):
    """1 M LiDAR-like points (x y z intensity) as binary_compressed, written by open3d: read identically, and in about
    the time open3d's own C++ reader takes (LZF in C, no Python loop over tokens)."""
    n = 1_000_000
    rng = np.random.default_rng(0)
    az = np.linspace(0, 200 * np.pi, n)
    r = 10 + 5 * np.sin(az / 7) + rng.normal(0, 0.02, n)
    pts = np.stack([r * np.cos(az), r * np.sin(az), np.round(0.3 * np.sin(az / 50), 2)], 1).astype(np.float32)
    inten = np.where(np.arange(n) % 3 == 0, 0, rng.integers(0, 256, n)).astype(np.float32)
    path = _o3d_t_write(tmp_path / "big.pcd", pts, inten, compressed=True)
    ours, theirs = [], []
    for _ in range(3):
        t = time.perf_counter()
        c = read_cloud(path)
        ours.append(time.perf_counter() - t)
        t = time.perf_counter()
        o3d.t.io.read_point_cloud(str(path))
        theirs.append(time.perf_counter() - t)
    assert np.array_equal(c.points, pts) and np.array_equal(c.intensity, inten)
    assert min(ours) < 2.0 * min(theirs) + 0.05, (ours, theirs)
    print(f"\n1M-point binary_compressed read: radarcal {min(ours):.3f} s, open3d {min(theirs):.3f} s")
