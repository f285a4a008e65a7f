"""``radarcal intrinsics``: chessboard / ChArUco intrinsics (and stereo extrinsics) into the bundle.

Parse -> :func:`radarcal.intrinsics.collect.collect_camera` (parallel detection, live coverage on a terminal) ->
:func:`radarcal.intrinsics.calibrate.calibrate` -> bundle + session -> print.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import numpy as np
import typer

from radarcal.bundle import load_or_create_bundle, save_bundle
from radarcal.cli.board_options import BOARD, BoardKind, BoardKindOpt, BoardLayout, ColsOpt, DictOpt, LayoutOpt, MarkerOpt, RowsOpt, SquareOpt, board_spec
from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console, parse_image_size
from radarcal.errors import InputError
from radarcal.intrinsics.select import DESCRIPTOR_NAMES
from radarcal.intrinsics.solve import MODELS

__all__ = ["intrinsics"]

CameraModel = Enum("CameraModel", {m: m for m in ("auto", *MODELS)}, type=str)  # auto | pinhole5 | pinhole8 | fisheye | pinhole4


def _collect(name: str, sources: list[str], board, workers: int):
    """One camera's views; a rich progress bar with the live X/Y/Size/Skew coverage when stderr is a terminal."""
    from radarcal.intrinsics.collect import LiveCoverage, collect_camera

    log = (lambda m: err_console.print(m)) if err_console.is_terminal else (lambda m: None)
    if not err_console.is_terminal:
        return collect_camera(name, sources, board, workers, log=log)
    from rich.progress import Progress

    live = LiveCoverage(board)
    with Progress(console=err_console, transient=True) as prog:
        task = prog.add_task(f"detecting {name} ({workers} workers)", total=None)

        def done(k: int, n: int, v) -> None:
            live.add(v)
            prog.update(task, completed=k, total=n, description=f"detecting {name}: {len(live.descriptors)} boards  {live.bars()}")

        return collect_camera(name, sources, board, workers, done, log)


def _bar(p: float, width: int = 20) -> str:
    n = int(round(max(0.0, min(1.0, p)) * width))
    return "#" * n + "." * (width - n)


def _human_camera(s: dict) -> None:
    K, sg = np.asarray(s["K"]), s["sigma"]
    typer.echo(f"camera {s['camera']}: {s['model']} {s['image_size'][0]}x{s['image_size'][1]}  RMS {s['rms_px']:.3f} px  (noise σ {s['noise_px']:.3f} px/coord)")
    if s.get("refined_by"):
        Km = np.asarray(s["mono"]["K"])
        typer.echo(f"  intrinsics from the {s['refined_by']} (mono solve: fx={Km[0, 0]:.3f} fy={Km[1, 1]:.3f} cx={Km[0, 2]:.3f} cy={Km[1, 2]:.3f}, RMS {s['mono']['rms_px']:.3f} px)")
    typer.echo(f"  fx = {K[0, 0]:.3f} ± {sg['fx']:.3f}   fy = {K[1, 1]:.3f} ± {sg['fy']:.3f}")
    typer.echo(f"  cx = {K[0, 2]:.3f} ± {sg['cx']:.3f}   cy = {K[1, 2]:.3f} ± {sg['cy']:.3f}")
    dn = [k for k in sg if k not in ("fx", "fy", "cx", "cy")]
    typer.echo("  dist: " + "  ".join(f"{n}={v:.5g}±{sg[n]:.2g}" for n, v in zip(dn, s["dist"])))
    typer.echo(f"  views used {s['views_used']}/{s['views_total']}, corners dropped as outliers: {s['corners_dropped']}")
    for n, why in s["rejected"].items():
        typer.echo(f"    rejected {n}: {why}")
    typer.echo("  coverage: " + "  ".join(f"{k} [{_bar(s['coverage'][k], 10)}] {s['coverage'][k]:.2f}" for k in DESCRIPTOR_NAMES) + f"  image {s['coverage']['image_grid']:.0%}")
    u = s["uncertainty"]
    typer.echo(f"  projection σ (a far point, worst direction): {u['centre_px']:.3f} px at the centre, median {u['median_px']:.3f} px, 90 % of the image below {u['p90_px']:.3f} px; "
               f"within 2x the centre's σ over {u['within_2x_centre_fraction']:.0%} of the image, below the corner noise ({u['threshold_px']:.3f} px) over {u['valid_fraction']:.0%}")
    if s.get("charuco_layout"):
        c = s["charuco_layout"]
        typer.echo(f"  ChArUco layout: {'legacy (pre-4.6)' if c['legacy'] else 'new (OpenCV >= 4.6)'} (corners found: new {c['corners_new_layout']}, legacy {c['corners_legacy_layout']})")
    if s.get("model_choice"):
        mc = s["model_choice"]
        typer.echo(f"  model auto -> {mc['model']}: {mc['reason']}")
        for r in mc["table"]:
            if "error" in r:
                typer.echo(f"    {r['model']:9s} failed: {r['error']}")
            else:
                typer.echo(f"    {r['model']:9s} RMS {r.get('rms_px', float('nan')):.3f} px  halves differ {r.get('diff_median_px', float('nan')):.3f} px vs σ {r.get('sigma_median_px', float('nan')):.3f} px  {'consistent' if r.get('consistent') else 'INCONSISTENT'}")
    elif s.get("crossval"):
        c = s["crossval"]
        typer.echo(f"  cross-validation (two halves): differ {c['diff_median_px']:.3f} px median (max {c['diff_max_px']:.2f}) vs σ {c['sigma_median_px']:.3f} px -> {'consistent' if c['consistent'] else 'INCONSISTENT'}")
    for w in s["warnings"]:
        typer.echo(f"  warning: {w}")


def _human(s: dict) -> None:
    for c in s["cameras"]:
        _human_camera(c)
    if "stereo" in s:
        x = s["stereo"]
        t = np.asarray(x["T_cam1_cam0"])[:3, 3]
        typer.echo(f"stereo {x['T']}: baseline {x['baseline_m'] * 1000:.3f} ± {x['sigma']['baseline_m'] * 1000:.3f} mm  t = ({t[0]:.5f}, {t[1]:.5f}, {t[2]:.5f}) m  RMS {x['rms_px']:.3f} px over {x['pairs']} pairs")
    if s["stored"]:
        typer.echo(f"written to {s['bundle']}" + (" (flagged: stored with --force)" if s["refused"] else ""))
    else:
        typer.echo(f"NOT stored ({'; '.join(s['refused'])}; --force to store anyway)")


def intrinsics(
    sources: list[str] = typer.Argument(None, help="Images, folders, globs or video files (the left camera with --right); or none with --corners."),
    corners: Path = typer.Option(None, "--corners", help="Corners detected by another tool instead of images: mrcal corners cache (.vnl) or CSV image,id,u,v (needs --image-size)."),
    image_size: str = typer.Option(None, "--image-size", help="WIDTHxHEIGHT of the images the --corners file was detected in."),
    board: BoardKindOpt = BoardKind(BOARD.kind),
    cols: ColsOpt = BOARD.cols,
    rows: RowsOpt = BOARD.rows,
    square: SquareOpt = BOARD.square,
    marker: MarkerOpt = None,
    dictionary: DictOpt = BOARD.dictionary,
    layout: LayoutOpt = BoardLayout.auto,
    camera: str = typer.Option("cam0", "--camera", help="Camera name in the bundle."),
    bundle: BundleOpt = ...,
    model: CameraModel = typer.Option(CameraModel("pinhole5"), "--model", help="auto | pinhole5 | pinhole4 (k3 = 0, for Kalibr radtan) | pinhole8 (rational) | fisheye (equidistant)."),
    stereo: bool = typer.Option(False, "--stereo", help="Stereo: SOURCE are the left images, --right the right ones (--right alone implies it)."),
    right: list[str] = typer.Option(None, "--right", help="Right-camera images/folder/glob (repeatable); implies --stereo."),
    right_camera: str = typer.Option("cam1", "--right-camera", help="Name of the right camera in the bundle."),
    fix_intrinsics: bool = typer.Option(False, "--fix-intrinsics", help="Stereo: keep the mono intrinsics (default: refine both jointly with T_cam1_cam0 over the pairs)."),
    workers: int = typer.Option(2, "--workers", help="Detection processes."),
    novelty: float = typer.Option(0.0, "--novelty", help="ROS novelty gate for still images (L1 in X/Y/Size/Skew; 0 = keep all). Videos always use 0.2."),
    no_crossval: bool = typer.Option(False, "--no-crossval", help="Skip the split-halves cross-validation."),
    k_sigma: float = typer.Option(4.0, "--k-sigma", help="Corner outlier threshold in σ."),
    force: bool = typer.Option(False, "--force", help="Store the intrinsics even when the cross-validation says INCONSISTENT (flagged in the bundle)."),
    as_json: JsonOpt = False,
) -> None:
    """Calibrate camera intrinsics from chessboard / ChArUco views (and T_cam1_cam0 with --right)."""
    from radarcal.intrinsics.calibrate import CameraViews, IntrinsicsOptions, calibrate
    from radarcal.intrinsics.collect import check_sources, views_from_corner_file

    spec = board_spec(board, cols, rows, square, marker, dictionary, layout)
    if stereo and not right:
        raise InputError("--stereo", "needs the right camera's images with --right")
    if (corners is None) == (not sources):
        raise InputError("SOURCES", "give images (or folders, globs, videos) or --corners FILE")
    if corners is not None and (right or image_size is None):
        raise InputError("--corners", "needs --image-size WxH (the corner file does not record it) and takes no --right")
    opts = IntrinsicsOptions(model=model.value, crossval=not no_crossval, novelty=novelty, k_sigma=k_sigma, joint_stereo=not fix_intrinsics)
    b = load_or_create_bundle(bundle)  # fail early on a broken bundle
    check_sources([*(sources or []), *(right or [])])  # and on a source that cannot be read, before any detection
    if corners is not None:
        left = CameraViews(camera, views_from_corner_file(corners, spec, parse_image_size(image_size)), spec, {}, [corners])
    else:
        left = _collect(camera, sources, spec, workers)
    run = calibrate(left, _collect(right_camera, list(right), spec, workers) if right else None, opts)
    stored = force or not run.refusals
    if stored:
        run.store(b, command_line())
        save_bundle(b)
    emit({"bundle": str(bundle), "stored": stored, **run.summary()}, as_json, _human)
    if not stored:
        raise typer.Exit(1)
