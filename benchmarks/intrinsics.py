"""``radarcal intrinsics`` against plain OpenCV on the same images.

Run: ``PYTHONPATH=$PWD python -m benchmarks intrinsics`` (``--quick``: 12 rendered views instead of 25).

Plain OpenCV = the tutorial pipeline: ``findChessboardCorners(ADAPTIVE_THRESH|NORMALIZE_IMAGE)`` +
``cornerSubPix(winSize=(11,11))`` + ``calibrateCamera`` on every image where a board was found.
Ours = ``radarcal.intrinsics`` (downscaled classic detection + adaptive window, SB fallback, blur/outlier rejection).

Sets:
1. rendered by ``radarcal.synth.write_board_set``: 1280x1024 radtan-5 camera, 9x6 chessboard, N views + 2 partial +
   1 bowed ("bad") view + 1 motion-blurred view + 2 blank frames + 1 truncated PNG — the truth is known;
2. OpenCV's real left13 set (reference: mrcal fx = 533.30, SOURCE.md);
3. corner-level simulations with one badly detected (bent) view, 5 seeds (1280x1024, 4 mm lens).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["main"]


def _plain_detect(path: str, pattern: tuple[int, int]):
    import cv2

    g = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if g is None:
        return None, None
    ok, c = cv2.findChessboardCorners(g, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None, g.shape[::-1]
    c = cv2.cornerSubPix(g, c.reshape(-1, 1, 2), (11, 11), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.001))
    return c.reshape(-1, 2).astype(float), g.shape[::-1]


def _plain_calibrate(obj, img, size):
    import cv2

    rms, K, dist, _r, _t = cv2.calibrateCamera([o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img], size, None, None)
    return rms, K, dist.ravel()


def _corner_err(uv: np.ndarray, truth_uv: np.ndarray) -> np.ndarray:
    """Per-corner error against the truth, accepting the 180° reversed order (chessboard ambiguity)."""
    a = np.linalg.norm(uv - truth_uv, axis=1)
    b = np.linalg.norm(uv[::-1] - truth_uv, axis=1)
    return a if a.mean() < b.mean() else b


def _proj_diff(cam_est, cam_true) -> float:
    """Median |project_est(ray_true(q)) - q| over a 32x26 grid (no rotation fitting: the absolute error)."""
    w, h = cam_true.image_size
    q = np.stack(np.meshgrid(np.linspace(0, w - 1, 32), np.linspace(0, h - 1, 26)), -1).reshape(-1, 2)
    uv, _ = cam_est.project(cam_true.unproject(q))
    return float(np.median(np.linalg.norm(uv - q, axis=1)))


def _busy(n: int) -> float:
    t = time.time()
    x = 0
    for i in range(n):
        x += i * i
    return time.time() - t


def _available_parallelism() -> float:
    """Control: speed-up of 4 pure-Python busy loops on 2 processes vs 1 right now (other users of the cores)."""
    from concurrent.futures import ProcessPoolExecutor

    n = 3_000_000
    t0 = time.time()
    for _ in range(4):
        _busy(n)
    t1 = time.time() - t0
    with ProcessPoolExecutor(2) as ex:
        list(ex.map(_busy, [1000, 1000]))  # start the workers first
        t0 = time.time()
        list(ex.map(_busy, [n] * 4))
        t2 = time.time() - t0
    return t1 / t2


def _rendered(n_views: int, seed: int) -> list[str]:
    from radarcal.board import BoardSpec, object_points
    from radarcal.camera import Camera
    from radarcal.intrinsics.collect import detect_files, expand_sources
    from radarcal.intrinsics.pipeline import run_intrinsics
    from radarcal.synth import default_camera, load_board_truth, write_board_set

    lines = []
    cam = default_camera("pinhole5", (1280, 1024))
    spec = BoardSpec("chessboard", 9, 6, 0.025)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.time()
        write_board_set(tmp, cam, spec, n_views=n_views, seed=seed, n_partial=2, n_blank=2, n_corrupt=1, bad_view=True, n_blurred=1)
        t_render = time.time() - t0
        truth = load_board_truth(tmp)
        files, _v = expand_sources([tmp])
        names = [str(f) for f in files]
        board = spec  # the same board model renders and detects
        # ours, one worker (time per image on one core), then two workers (speed-up)
        t0 = time.time()
        views1 = detect_files(files, board, workers=1)
        t_ours1 = time.time() - t0
        t0 = time.time()
        detect_files(files, board, workers=2)
        t_ours2 = time.time() - t0  # includes starting the worker processes
        t0 = time.time()
        detect_files(files, board, workers=2)
        t_ours2w = time.time() - t0  # forkserver already running
        control = _available_parallelism()
        t0 = time.time()
        res = run_intrinsics([v.name for v in views1], [v.detection for v in views1], board, [v.error for v in views1], model="pinhole5", crossval=False)
        t_solve = time.time() - t0
        # plain OpenCV
        t0 = time.time()
        plain = [_plain_detect(n, (9, 6)) for n in names]
        t_plain = time.time() - t0
        obj_all = object_points(board)
        found = [(n, uv) for n, (uv, _s) in zip(names, plain) if uv is not None]
        rms_p, K_p, d_p = _plain_calibrate([obj_all] * len(found), [uv for _n, uv in found], (1280, 1024))
        cam_p = Camera((1280, 1024), K_p, d_p[:5])
        # corner accuracy on the clean full views
        by_file = {v["file"]: v for v in truth.views}
        e_ours, e_plain = [], []
        for n, v1, (uvp, _s) in zip(names, views1, plain):
            tv = by_file.get(Path(n).name)
            if tv is None or tv["kind"] != "full":
                continue
            t_uv = np.asarray(tv["uv"], float)
            if v1.detection is not None and v1.detection.ok:
                e_ours.append(_corner_err(v1.detection.uv, t_uv))
            if uvp is not None:
                e_plain.append(_corner_err(uvp, t_uv))
        e_ours = np.concatenate(e_ours)
        e_plain = np.concatenate(e_plain)
        true = np.array([truth.camera.fx, truth.camera.fy, truth.camera.cx, truth.camera.cy])
        c = res.calibration
        d_ours = c.params[:4] - true
        d_plain = np.array([K_p[0, 0], K_p[1, 1], K_p[0, 2], K_p[1, 2]]) - true
        n_img = len(names)
        rej = [f"{Path(n).name}={s.split(' (')[0]}" for n, s in zip(res.names, res.status) if s != "used"]
        lines += [
            f"rendered 1280x1024 set (seed {seed}): {n_img} files = {n_views} board views (2 partial, 1 bowed, 1 motion-blurred) + 2 blank + 1 corrupt; rendering took {t_render:.1f} s",
            "| | plain OpenCV | radarcal | ratio |",
            "|---|---|---|---|",
            f"| detection s/image, 1 core (all {n_img} files) | {t_plain / n_img:.3f} | {t_ours1 / n_img:.3f} | {t_plain / max(t_ours1, 1e-9):.1f}x faster |",
            f"| detection wall s/image, 2 workers (incl. process start) | - | {t_ours2 / n_img:.3f} | speed-up {t_ours1 / max(t_ours2, 1e-9):.2f}x |",
            f"| detection wall s/image, 2 workers (warm) | - | {t_ours2w / n_img:.3f} | speed-up {t_ours1 / max(t_ours2w, 1e-9):.2f}x |",
            f"| control: CPU-bound busy loop, 2 processes vs 1, same moment | - | - | speed-up {control:.2f}x (2.0 = two free cores) |",
            f"| corner error vs truth, RMS px (clean views) | {np.sqrt(np.mean(e_plain**2)):.3f} | {np.sqrt(np.mean(e_ours**2)):.3f} | {np.sqrt(np.mean(e_plain**2)) / np.sqrt(np.mean(e_ours**2)):.1f}x |",
            f"| views used | {len(found)} (all found) | {int(c.view_used.sum())} | |",
            f"| reprojection RMS px | {rms_p:.3f} | {c.rms_px:.3f} | |",
            f"| Δfx Δfy Δcx Δcy px | {' '.join(f'{x:+.3f}' for x in d_plain)} | {' '.join(f'{x:+.3f}' for x in d_ours)} | |",
            f"| max abs Δ (fx fy cx cy) px | {np.abs(d_plain).max():.3f} | {np.abs(d_ours).max():.3f} | {np.abs(d_plain).max() / max(np.abs(d_ours).max(), 1e-9):.1f}x |",
            f"| median projection error over the image px | {_proj_diff(cam_p, truth.camera):.3f} | {_proj_diff(c.camera, truth.camera):.3f} | |",
            f"| solve + σ + uncertainty map s | - | {t_solve:.2f} | |",
            f"radarcal σ(fx fy cx cy) = {' '.join(f'{c.sigma[k]:.3f}' for k in ('fx', 'fy', 'cx', 'cy'))} px; rejected: {', '.join(rej)}",
            "",
        ]
    return lines


def _opencv_left() -> list[str]:
    from radarcal.board import BoardSpec, object_points
    from radarcal.intrinsics.detect import detect_board
    from radarcal.intrinsics.solve import calibrate

    d = Path(__file__).resolve().parents[1].parent / "shared" / "datasets" / "opencv_stereo_chessboard"
    if not d.is_dir():
        return [f"(OpenCV sample set not found at {d}: skipped)", ""]
    import cv2

    files = sorted(str(p) for p in d.glob("left*.jpg"))
    board = BoardSpec("chessboard", 9, 6, 0.025)
    plain = [_plain_detect(f, (9, 6))[0] for f in files]
    rms_p, K_p, _ = _plain_calibrate([object_points(board)] * len(plain), plain, (640, 480))
    dets = [detect_board(cv2.imread(f, cv2.IMREAD_GRAYSCALE), board) for f in files]
    cal = calibrate([object_points(board)] * len(dets), [x.uv for x in dets], (640, 480))
    return [
        "OpenCV sample left set (13 x 640x480, real): reference mrcal fx = 533.30 (SOURCE.md)",
        "| | plain OpenCV | radarcal |",
        "|---|---|---|",
        f"| RMS px | {rms_p:.4f} | {cal.rms_px:.4f} |",
        f"| fx - 533.30 px | {K_p[0, 0] - 533.30:+.2f} | {cal.camera.fx - 533.30:+.2f} (σ {cal.sigma['fx']:.2f}) |",
        "",
    ]


def _bad_view_sim(seeds=range(100, 105)) -> list[str]:
    import cv2

    from radarcal.board import BoardSpec
    from radarcal.synth.intrinsics_views import radar_station_camera, simulate_views
    from radarcal.intrinsics.solve import calibrate

    board = BoardSpec("chessboard", 14, 10, 0.03)
    cam = radar_station_camera()
    true = np.array([cam.fx, cam.fy, cam.cx, cam.cy])
    ep, eo = [], []
    for seed in seeds:
        sim = simulate_views(cam, board, 25, 0.2, np.random.default_rng(seed), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)
        imgs = [i.copy() for i in sim.image_points]
        g = imgs[3].reshape(10, 14, 2)
        g[..., 1] += 6.0 * np.linspace(-1, 1, 14)[None, :] ** 2
        imgs[3] = g.reshape(-1, 2)
        _rms, K, _d, _r, _t = cv2.calibrateCamera([o.astype(np.float32) for o in sim.object_points], [i.astype(np.float32) for i in imgs], cam.image_size, None, None)
        ep.append(K[[0, 1, 0, 1], [0, 1, 2, 2]] - true)
        eo.append(calibrate(sim.object_points, imgs, cam.image_size).params[:4] - true)
    ep, eo = np.abs(ep), np.abs(eo)
    return [
        f"corner-level simulation, 1280x1024 (fx 833), 25 views of 14x10, noise 0.2 px, one view bent by up to 6 px; {len(ep)} seeds",
        "| mean abs error px | plain calibrateCamera | radarcal (rejection) |",
        "|---|---|---|",
        *[f"| {k} | {ep[:, i].mean():.3f} (max {ep[:, i].max():.2f}) | {eo[:, i].mean():.3f} (max {eo[:, i].max():.2f}) |" for i, k in enumerate(("fx", "fy", "cx", "cy"))],
        "",
    ]


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    out = ["# benchmarks.intrinsics", ""]
    out += _rendered(12 if quick else 25, seed=21)
    out += _opencv_left()
    out += _bad_view_sim(range(100, 102) if quick else range(100, 105))
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
