"""``radarcal synth board``: a calibration-target image set (PNGs + truth.json) with known intrinsics and poses."""

from __future__ import annotations

import time
from enum import Enum
from pathlib import Path

import typer

from radarcal.cli.board_options import BOARD, BoardKind, BoardKindOpt, BoardLayout, ColsOpt, DictOpt, LayoutOpt, MarkerOpt, RowsOpt, SquareOpt, board_spec
from radarcal.cli.common import JsonOpt, command_line, emit, parse_image_size, progress
from radarcal.io.outputs import check_output
from radarcal.errors import InputError


class RenderModel(str, Enum):
    pinhole5 = "pinhole5"
    pinhole8 = "pinhole8"
    fisheye = "fisheye"


class ViewCoverage(str, Enum):
    full = "full"
    poor = "poor"


def synth_board(
    out_dir: Path = typer.Argument(..., help="Folder to write img_NNN.png and truth.json into (created if missing)."),
    board: BoardKindOpt = BoardKind(BOARD.kind),
    cols: ColsOpt = BOARD.cols,
    rows: RowsOpt = BOARD.rows,
    square: SquareOpt = BOARD.square,
    marker: MarkerOpt = None,
    dictionary: DictOpt = BOARD.dictionary,
    layout: LayoutOpt = BoardLayout.auto,
    image_size: str = typer.Option("1280x1024", "--image-size", help="Image size WIDTHxHEIGHT."),
    model: RenderModel = typer.Option(RenderModel.pinhole5, "--model", help="Default camera of this model for the size (fisheye: equidistant)."),
    fov: float = typer.Option(190.0, "--fov", help="Fisheye: field of view (deg) of the image circle (spans the image height)."),
    camera_file: Path = typer.Option(None, "--camera-file", help="Use these intrinsics instead (ROS/OpenCV/Kalibr/radarcal file)."),
    views: int = typer.Option(25, "--views", min=0, help="Images showing the board (including partial and bad views)."),
    partial: int = typer.Option(None, "--partial", min=0, help="How many of the views show the board partly outside the image (default 8 % of --views: 2 of 25)."),
    blank: int = typer.Option(2, "--blank", min=0, help="Extra frames without a board."),
    corrupt: int = typer.Option(1, "--corrupt", min=0, help="Extra truncated (unreadable) PNG files."),
    noise: float = typer.Option(0.5, "--noise", min=0.0, help="Sensor noise sigma in grey levels (0..255 scale)."),
    blur: float = typer.Option(0.6, "--blur", min=0.0, help="Optical blur sigma in px."),
    vignetting: float = typer.Option(0.25, "--vignetting", min=0.0, max=0.999, help="Relative darkening at the image corners."),
    supersample: int = typer.Option(4, "--supersample", min=1, help="Sub-samples per pixel axis at edges (>= S*S samples)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed -> bit-identical files)."),
    coverage: ViewCoverage = typer.Option(ViewCoverage.full, "--coverage", help="full, or poor (board kept in the upper-left of the image)."),
    bad_view: bool = typer.Option(False, "--bad-view", help="One view with a bowed (non-flat) pattern: an outlier."),
    bad_px: float = typer.Option(1.5, "--bad-px", help="Largest corner displacement of the bad view in px."),
    stereo_baseline: float = typer.Option(0.0, "--stereo-baseline", min=0.0, max=10.0, help="Baseline (m) of a second camera (cam0/ and cam1/ folders); 0 = mono."),
    video: float = typer.Option(0.0, "--video", min=0.0, max=600.0, help="Also write video.avi (MJPG) of this many seconds: the board moving through the views."),
    fps: float = typer.Option(10.0, "--fps", min=1.0, max=120.0, help="Video frame rate."),
    blurred: int = typer.Option(0, "--blurred", min=0, help="How many of the views get a motion streak (1-1.6 % of the image width)."),
    as_json: JsonOpt = False,
) -> None:
    """Render a calibration-target image set with known camera, poses and corner pixels."""
    from radarcal.synth.board import RenderSettings, default_camera, default_stereo_camera, write_board_set
    from radarcal.synth.board_set import board_set_summary

    partial = int(round(0.08 * views)) if partial is None else partial
    if partial > views:
        raise InputError("--partial", f"{partial} partial views but only {views} views")
    if camera_file is not None:
        from radarcal.io import import_camera

        camera, _fmt = import_camera(camera_file, None)
    else:
        if not (60.0 <= fov <= 270.0):
            raise InputError("--fov", f"expected 60..270 degrees, got {fov:g}")
        w, h = parse_image_size(image_size)
        if not (16 <= w <= 20000 and 16 <= h <= 20000):
            raise InputError("--image-size", f"image size out of range: {w}x{h}")
        camera = default_camera(model.value, (w, h), fisheye_fov_deg=fov)
    spec = board_spec(board, cols, rows, square, marker, dictionary, layout)
    check_output(out_dir, what="image folder", folder=True)
    settings = RenderSettings(supersample=supersample, blur_sigma=blur, noise_sigma=noise, vignetting=vignetting, fisheye_fov_deg=fov)
    rig = default_stereo_camera(camera, stereo_baseline) if stereo_baseline > 0 else None

    # the command as typed, with the output folder replaced so that the same call elsewhere gives the same bytes
    command = " ".join("OUT_DIR" if a and not a.startswith("-") and Path(a) == Path(out_dir) else a for a in command_line().split(" "))
    t0 = time.perf_counter()
    try:
        truth = write_board_set(out_dir, camera, spec, n_views=views, seed=seed, settings=settings, coverage=coverage.value,
                                n_partial=partial, n_blank=blank, n_corrupt=corrupt, bad_view=bad_view,
                                bad_px=bad_px, n_blurred=blurred, stereo=rig, video_seconds=video, video_fps=fps,
                                command=command, progress=lambda it: progress(it, "rendering", total=len(it)))
    except ValueError as e:
        raise InputError("--board/--image-size", str(e)) from None
    except OSError as e:
        raise InputError(out_dir, f"cannot write: {e.strerror or e}") from None
    summary = board_set_summary(truth, out_dir, time.perf_counter() - t0)
    emit(summary, as_json, _human)


def _human(s: dict) -> None:
    """The summary for people."""
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

