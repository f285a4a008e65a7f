"""``radarcal synth board``: a calibration-target image set (PNGs + truth.json) with known intrinsics and poses."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, command_line, emit, progress
from radarcal.cli.outputs import check_output
from radarcal.errors import InputError

_MODELS = ("pinhole5", "pinhole8", "fisheye")


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError("--size", f"expected WIDTHxHEIGHT such as 1280x1024, got {text!r}") from None
    if not (16 <= w <= 20000 and 16 <= h <= 20000):
        raise InputError("--size", f"image size out of range: {w}x{h}")
    return w, h


def synth_board(
    out_dir: Path = typer.Argument(..., help="Folder to write img_NNN.png and truth.json into (created if missing)."),
    board: str = typer.Option("chessboard", "--board", help="chessboard | charuco"),
    cols: int = typer.Option(9, "--cols", help="Chessboard: inner corners along x. ChArUco: squares along x."),
    rows: int = typer.Option(6, "--rows", help="Chessboard: inner corners along y. ChArUco: squares along y."),
    square: float = typer.Option(0.025, "--square", help="Square size in metres."),
    marker: float = typer.Option(None, "--marker", help="ChArUco marker size in metres (default 0.75 x square)."),
    dictionary: str = typer.Option("DICT_4X4_1000", "--dict", help="ChArUco ArUco dictionary (OpenCV name)."),
    legacy: bool = typer.Option(False, "--legacy", help="ChArUco: OpenCV's legacy (pre-4.6) layout."),
    size: str = typer.Option("1280x1024", "--size", help="Image size WIDTHxHEIGHT."),
    model: str = typer.Option("pinhole5", "--model", help="pinhole5 | pinhole8 | fisheye (default camera for the size)."),
    fov: float = typer.Option(190.0, "--fov", help="Fisheye: field of view (deg) of the image circle (spans the image height)."),
    camera_file: Path = typer.Option(None, "--camera", help="Use these intrinsics instead (ROS/OpenCV/Kalibr/radarcal file)."),
    views: int = typer.Option(25, "--views", help="Images showing the board (including partial and bad views)."),
    partial: int = typer.Option(None, "--partial", help="How many of the views show the board partly outside the image (default 8 % of --views: 2 of 25)."),
    blank: int = typer.Option(2, "--blank", help="Extra frames without a board."),
    corrupt: int = typer.Option(1, "--corrupt", help="Extra truncated (unreadable) PNG files."),
    noise: float = typer.Option(0.5, "--noise", help="Sensor noise sigma in grey levels (0..255 scale)."),
    blur: float = typer.Option(0.6, "--blur", help="Optical blur sigma in px."),
    vignetting: float = typer.Option(0.25, "--vignetting", help="Relative darkening at the image corners."),
    supersample: int = typer.Option(4, "--supersample", help="Sub-samples per pixel axis at edges (>= S*S samples)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed -> bit-identical files)."),
    coverage: str = typer.Option("full", "--coverage", help="full | poor (board kept in the upper-left of the image)."),
    bad_view: bool = typer.Option(False, "--bad-view", help="One view with a bowed (non-flat) pattern: an outlier."),
    bad_px: float = typer.Option(1.5, "--bad-px", help="Largest corner displacement of the bad view in px."),
    stereo: float = typer.Option(0.0, "--stereo", help="Baseline in metres of a second camera (cam0/ and cam1/ folders); 0 = mono."),
    video: float = typer.Option(0.0, "--video", help="Also write video.avi (MJPG) of this many seconds: the board moving through the views."),
    fps: float = typer.Option(10.0, "--fps", help="Video frame rate."),
    blurred: int = typer.Option(0, "--blurred", help="How many of the views get a motion streak (1-1.6 % of the image width)."),
    as_json: JsonOpt = False,
) -> None:
    """Render a calibration-target image set with known camera, poses and corner pixels."""
    from radarcal.board import BoardSpec
    from radarcal.synth.board import RenderSettings, default_camera, default_stereo_camera, write_board_set

    if board not in ("chessboard", "charuco"):
        raise InputError("--board", f"expected chessboard or charuco, got {board!r}")
    if model not in _MODELS:
        raise InputError("--model", f"expected one of {', '.join(_MODELS)}, got {model!r}")
    if coverage not in ("full", "poor"):
        raise InputError("--coverage", f"expected full or poor, got {coverage!r}")
    if partial is None:
        partial = int(round(0.08 * views))
    for name, value in (("--views", views), ("--partial", partial), ("--blank", blank), ("--corrupt", corrupt), ("--blurred", blurred)):
        if value < 0:
            raise InputError(name, f"must be >= 0, got {value}")
    if partial > views:
        raise InputError("--partial", f"{partial} partial views but only {views} views")
    if noise < 0 or blur < 0 or supersample < 1 or not (0 <= vignetting < 1):
        raise InputError("--noise/--blur/--supersample/--vignetting", "out of range")
    if camera_file is not None:
        from radarcal.io import import_camera

        camera, _fmt = import_camera(camera_file, None)
    else:
        if not (60.0 <= fov <= 270.0):
            raise InputError("--fov", f"expected 60..270 degrees, got {fov:g}")
        camera = default_camera(model, _parse_size(size), fisheye_fov_deg=fov)
    if board == "charuco" and marker is None:
        marker = 0.75 * square
    try:
        charuco = board == "charuco"
        spec = BoardSpec(board, cols, rows, square, marker if charuco else None, dictionary, legacy if charuco else None)
    except ValueError as e:
        raise InputError("--board", str(e)) from None
    check_output(out_dir, what="image folder", folder=True)
    settings = RenderSettings(supersample=supersample, blur_sigma=blur, noise_sigma=noise, vignetting=vignetting, fisheye_fov_deg=fov)

    if video < 0 or video > 600 or not (1 <= fps <= 120):
        raise InputError("--video/--fps", f"expected 0..600 s at 1..120 fps, got {video:g} s at {fps:g} fps")
    if stereo < 0 or stereo > 10:
        raise InputError("--stereo", f"baseline must be in 0..10 m, got {stereo:g}")
    rig = default_stereo_camera(camera, stereo) if stereo > 0 else None

    def prog(it):
        return progress(it, "rendering", total=len(it))

    # the command as typed, with the output folder replaced so that the same call elsewhere gives the same bytes
    command = " ".join("OUT_DIR" if a and not a.startswith("-") and Path(a) == Path(out_dir) else a for a in command_line().split(" "))
    t0 = time.perf_counter()
    try:
        truth = write_board_set(out_dir, camera, spec, n_views=views, seed=seed, settings=settings, coverage=coverage,
                                n_partial=partial, n_blank=blank, n_corrupt=corrupt, bad_view=bad_view,
                                bad_px=bad_px, n_blurred=blurred, stereo=rig, video_seconds=video, video_fps=fps,
                                command=command, progress=prog)
    except ValueError as e:
        raise InputError("--board/--size", str(e)) from None
    except OSError as e:
        raise InputError(out_dir, f"cannot write: {e.strerror or e}") from None
    elapsed = time.perf_counter() - t0
    files = truth["files"]
    summary = {
        "out_dir": str(out_dir),
        "truth": str(Path(out_dir) / "truth.json"),
        "model": truth["model"],
        "camera": truth["camera"],
        "board": truth["board"],
        "n_files": len(files["all"]),
        "files": {k: v for k, v in files.items() if k != "all"},
        "seconds": round(elapsed, 2),
    }
    if "video" in truth:
        summary["video"] = {k: truth["video"][k] for k in ("file", "fps", "n_frames", "keyframes")}
    if "stereo" in truth:
        summary["stereo"] = {k: v for k, v in truth["stereo"].items() if k != "files1"}

    def human(s: dict) -> None:
        c = s["camera"]
        K = c["K"]
        b = s["board"]
        shape = f"{b['cols']}x{b['rows']} {'inner corners' if b['type'] == 'chessboard' else 'squares'}"
        per = " per camera" if "stereo" in s else ""
        typer.echo(f"wrote {s['n_files']} files{per} + truth.json to {s['out_dir']} in {s['seconds']:.1f} s")
        typer.echo(f"  camera: {s['model']} {c['image_size'][0]}x{c['image_size'][1]} fx={K[0][0]:.3f} fy={K[1][1]:.3f} "
                   f"cx={K[0][2]:.3f} cy={K[1][2]:.3f} dist={[round(x, 6) for x in c['dist']]}")
        typer.echo(f"  board: {b['type']}{' (legacy)' if b['legacy'] else ''} {shape}, square {b['square'] * 1000:g} mm"
                   + (f", marker {b['marker'] * 1000:g} mm {b['dictionary']}" if b["type"] == "charuco" else ""))
        f = s["files"]
        typer.echo(f"  views: {len(f['full'])} full, {len(f['partial'])} partial, {len(f['bad'])} bad, {len(f['blurred'])} blurred, "
                   f"{len(f['blank'])} blank, {len(f['corrupt'])} corrupt")
        if "video" in s:
            vd = s["video"]
            typer.echo(f"  video: {vd['file']} {vd['n_frames']} frames at {vd['fps']:g} fps, key poses at frames {vd['keyframes']}")
        if "stereo" in s:
            st = s["stereo"]
            typer.echo(f"  stereo: cam1 {st['model1']} fx={st['camera1']['K'][0][0]:.3f}, baseline {st['baseline_m'] * 1000:.2f} mm "
                       f"(cam0/ and cam1/, T_cam1_cam0 in truth.json)")
        for kind in ("partial", "bad", "blurred", "blank", "corrupt"):
            if f[kind]:
                typer.echo(f"  {kind}: {', '.join(f[kind])}")

    emit(summary, as_json, human)
