"""``radarcal intrinsics``: chessboard / ChArUco intrinsics (and stereo extrinsics) into the bundle.

Parse → detect (parallel) → :func:`radarcal.intrinsics.pipeline.run_intrinsics` → bundle + session → print.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from radarcal.board import BoardSpec, object_points
from radarcal.bundle import Provenance, hash_inputs, load_or_create_bundle, save_bundle
from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console
from radarcal.errors import InputError
from radarcal.cli.bundle_cmd import parse_image_size
from radarcal.intrinsics.collect import ViewInput, decide_layout, detect_files, diagnose, expand_sources, sample_video, views_from_corner_file
from radarcal.intrinsics.detect import normalise_order
from radarcal.intrinsics.pipeline import IntrinsicsResult, NotEnoughViews, run_intrinsics
from radarcal.intrinsics.session import IntrinsicsSession, StereoSession
from radarcal.intrinsics.select import DESCRIPTOR_NAMES, TARGET_RANGES, view_descriptor
from radarcal.intrinsics.solve import MODELS, SolveError
from radarcal.intrinsics.stereo import StereoResult, pair_by_name, stereo_calibrate

__all__ = ["intrinsics"]


def _collect(sources: list[str], board: BoardSpec, workers: int, label: str) -> tuple[list[ViewInput], BoardSpec, dict, list[Path]]:
    images, videos = expand_sources(sources)
    board, layout_info = decide_layout(images, board)
    views: list[ViewInput] = []
    if images:
        if err_console.is_terminal:
            from rich.progress import Progress

            with Progress(console=err_console, transient=True) as prog:
                title = f"detecting {label} ({len(images)} images, {workers} workers)"
                task = prog.add_task(title, total=len(images))
                descs: list[np.ndarray] = []

                def done(k: int, n: int, v: ViewInput) -> None:
                    # ROS-style live coverage bars: X / Y / Size / Skew of the boards found so far
                    d = v.detection
                    if d is not None and d.ok:
                        descs.append(view_descriptor(d.uv, d.ids, board.grid_shape, d.image_size))
                    bars = ""
                    if descs:
                        a = np.array(descs)
                        prog_ = np.minimum((a.max(axis=0) - a.min(axis=0)) / TARGET_RANGES, 1.0)
                        bars = "  " + " ".join(f"{nm} " + "█" * int(round(p * 5)) + "·" * (5 - int(round(p * 5))) for nm, p in zip(DESCRIPTOR_NAMES, prog_))
                    prog.update(task, completed=k, description=f"{title}: {len(descs)} boards{bars}")

                views += detect_files(images, board, workers, done)
        else:
            views += detect_files(images, board, workers)
    for v in videos:
        if err_console.is_terminal:
            err_console.print(f"sampling frames of {v} ...")
        views += sample_video(v, board, workers=workers)
    return views, board, layout_info, images + videos


def _solve(views: list[ViewInput], board: BoardSpec, files: list[Path], model: str, crossval: bool, novelty: float, k_sigma: float) -> IntrinsicsResult:
    names = [v.name for v in views]
    dets = [v.detection for v in views]
    errs = [v.error for v in views]
    try:
        return run_intrinsics(names, dets, board, errs, model=model, crossval=crossval, novelty=novelty, k_sigma=k_sigma)
    except NotEnoughViews as e:
        n_board = sum(1 for d in dets if d is not None and d.ok)
        detail = "; ".join(sorted({(v.error or (v.detection.reason if v.detection else "")) for v in views if not (v.detection and v.detection.ok)} - {""}))[:300]
        without = [Path(v.name) for v in views if not (v.detection and v.detection.ok) and Path(v.name).is_file()]
        hint = diagnose(without, board) if without else None  # a wrong --cols/--rows/--dict finds a stray board or none
        kind = "chessboard" if board.kind == "chessboard" else "ChArUco board"
        what = f"{board.cols}x{board.rows} {kind}"
        if n_board == 0:
            msg = f"no {what} found in any of {len(views)} inputs" + (f": {hint}" if hint else f" ({detail})" if detail else "")
        else:
            msg = f"{e}: the {what} was found in {n_board} of {len(views)} inputs" + (f"; {hint}" if hint else f"; rejected: {detail}")
        raise InputError(_where(files), msg) from None
    except SolveError as e:
        raise InputError(_where(files), str(e)) from None


def _where(files: list[Path]) -> Path | str:
    """The input to name in an error: the one file, or the folder of several."""
    if not files:
        return "SOURCE"
    return files[0] if len(files) == 1 else files[0].parent


def _check_sources(sources: list[str]) -> None:
    """Every SOURCE exists (expand_sources), and a file named explicitly (not found in a folder or by a glob, where
    unreadable frames are only rejected views) is a readable image or a video (InputError naming it)."""
    from radarcal.intrinsics.collect import VIDEO_EXTS
    from radarcal.io import read_image

    expand_sources(sources)
    for s in sources:
        p = Path(s)
        if p.is_file() and p.suffix.lower() not in VIDEO_EXTS:
            read_image(p, grayscale=True)


def _uncertainty_summary(unc) -> dict:
    """What the projection-σ map says: the centre, median and 90th percentile (px), where it is within 2x the
    centre's (what this data set can give), and where it is below the per-corner noise (``valid_fraction``)."""
    sig = np.asarray(unc.sigma_px, float)
    finite = sig[np.isfinite(sig)]
    centre = unc.at_centre()
    return {"centre_px": centre, "median_px": float(np.median(finite)) if finite.size else float("nan"), "p90_px": float(np.percentile(finite, 90)) if finite.size else float("nan"),
            "within_2x_centre_fraction": float(np.mean(np.isfinite(sig) & (sig <= 2 * centre))), "valid_fraction": unc.valid_fraction, "threshold_px": unc.threshold_px,
            "valid_means": "projection σ below the per-corner noise σ (threshold_px)"}


def _summary(name: str, res: IntrinsicsResult, layout_info: dict) -> dict:
    cal = res.calibration
    cam = cal.camera
    s = {
        "camera": name,
        "model": cal.model,
        "image_size": list(cam.image_size),
        "K": cam.K,
        "dist": cam.dist,
        "rms_px": cal.rms_px,
        "noise_px": cal.noise_px,
        "sigma": cal.sigma,
        "views_total": len(res.names),
        "views_used": int(cal.view_used.sum()),
        "corners_dropped": cal.dropped_corners,
        "rejected": {n: st for n, st in zip(res.names, res.status) if st != "used"},
        "coverage": {**{k: round(v, 3) for k, v in res.coverage.progress.items()}, "image_grid": round(res.coverage.grid_fraction, 3)},
        "uncertainty": _uncertainty_summary(res.uncertainty),
        "crossval": res.crossval.summary() if res.crossval else None,
        "model_choice": {"model": res.model_choice.model, "reason": res.model_choice.reason, "table": res.model_choice.table} if res.model_choice else None,
        "warnings": res.warnings,
    }
    if layout_info:
        s["charuco_layout"] = {"legacy": layout_info.get("legacy"), "corners_new_layout": layout_info.get("corners_new_layout"), "corners_legacy_layout": layout_info.get("corners_legacy_layout")}
    return s


def _bar(p: float, width: int = 20) -> str:
    n = int(round(max(0.0, min(1.0, p)) * width))
    return "#" * n + "." * (width - n)


def _human_camera(s: dict) -> None:
    K = np.asarray(s["K"])
    sg = s["sigma"]
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


def _stereo(res0: IntrinsicsResult, res1: IntrinsicsResult, board: BoardSpec, joint: bool) -> tuple[StereoResult, list[tuple[str, str]]]:
    used0 = {res0.names[i]: k for k, i in enumerate(res0.view_index) if res0.calibration.view_used[k]}
    used1 = {res1.names[i]: k for k, i in enumerate(res1.view_index) if res1.calibration.view_used[k]}
    pairs = pair_by_name(res0.names, res1.names)
    obj_all = object_points(board)
    objs, q0, q1, names = [], [], [], []
    for i, j in pairs:
        a, b = res0.names[i], res1.names[j]
        if a not in used0 or b not in used1:
            continue
        d0, d1 = res0.detections[i], res1.detections[j]
        if board.kind == "chessboard":
            uv1 = normalise_order(d1.uv, board.grid_shape, reference=d0.uv)
            objs.append(obj_all)
            q0.append(d0.uv)
            q1.append(uv1)
        else:
            common, i0, i1 = np.intersect1d(d0.ids, d1.ids, return_indices=True)
            if len(common) < 6:
                continue
            objs.append(obj_all[common])
            q0.append(d0.uv[i0])
            q1.append(d1.uv[i1])
        names.append((a, b))
    if not names:
        raise InputError("--right", "no synchronised pair has the board in both images (pairing is by the number in the file names)")
    return stereo_calibrate(res0.camera, res1.camera, objs, q0, q1, refine_intrinsics=joint), names


def intrinsics(
    sources: list[str] = typer.Argument(None, help="Images, folders, globs or video files (the left camera with --right); or none with --corners."),
    corners: Path = typer.Option(None, "--corners", help="Corners detected by another tool instead of images: mrcal corners cache (.vnl) or CSV image,id,u,v (needs --image-size)."),
    image_size: str = typer.Option(None, "--image-size", help="WIDTHxHEIGHT of the images the --corners file was detected in."),
    board: str = typer.Option("chessboard", "--board", help="chessboard | charuco"),
    cols: int = typer.Option(..., "--cols", help="Chessboard: inner corners per row. ChArUco: squares per row."),
    rows: int = typer.Option(..., "--rows", help="Chessboard: inner corners per column. ChArUco: squares per column."),
    square: float = typer.Option(..., "--square", help="Square size (m)."),
    marker: float = typer.Option(0.0, "--marker", help="ChArUco marker size (m)."),
    dictionary: str = typer.Option("DICT_4X4_1000", "--dict", help="ChArUco ArUco dictionary."),
    layout: str = typer.Option("auto", "--layout", help="ChArUco layout: auto | new | legacy."),
    camera: str = typer.Option("cam0", "--camera", help="Camera name in the bundle."),
    bundle: BundleOpt = ...,
    model: str = typer.Option("pinhole5", "--model", help="auto | pinhole5 | pinhole4 (k3 = 0, for Kalibr radtan) | pinhole8 (rational) | fisheye (equidistant)."),
    stereo: bool = typer.Option(False, "--stereo", help="Stereo: SOURCE are the left images, --right the right ones."),
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
    layouts = {"auto": None, "new": False, "legacy": True}
    if layout not in layouts:
        raise InputError("--layout", f"expected auto, new or legacy, got {layout!r}")
    try:
        spec = BoardSpec(board, cols, rows, square, marker, dictionary, layouts[layout])
    except ValueError as e:
        raise InputError("--board", str(e)) from None
    if model != "auto" and model not in MODELS:
        raise InputError("--model", f"expected auto or one of {', '.join(MODELS)}, got {model!r}")
    if stereo and not right:
        raise InputError("--stereo", "needs the right camera's images with --right")
    if (corners is None) == (not sources):
        raise InputError("SOURCES", "give images (or folders, globs, videos) or --corners FILE")
    if corners is not None and (right or image_size is None):
        raise InputError("--corners", "needs --image-size WxH (the corner file does not record it) and takes no --right")
    b = load_or_create_bundle(bundle)  # fail early on a broken bundle
    _check_sources([*(sources or []), *(right or [])])  # and on a source that cannot be read, before any detection

    if corners is not None:
        views0, spec0, layout0, files0 = views_from_corner_file(corners, spec, parse_image_size(image_size)), spec, {}, [corners]
    else:
        views0, spec0, layout0, files0 = _collect(sources, spec, workers, camera)
    res0 = _solve(views0, spec0, files0, model, not no_crossval, novelty, k_sigma)
    results = [(camera, res0, layout0, files0)]
    st = None
    if right:
        views1, spec1, layout1, files1 = _collect(list(right), spec, workers, right_camera)
        res1 = _solve(views1, spec1, files1, model, not no_crossval, novelty, k_sigma)
        results.append((right_camera, res1, layout1, files1))
        st, pair_names = _stereo(res0, res1, spec0, not fix_intrinsics)

    refusals = [f"{name}: cross-validation INCONSISTENT (halves differ {res.crossval.diff_median_px:.2f} px vs σ {res.crossval.sigma_median_px:.2f} px)"
                for name, res, _, _ in results if res.crossval is not None and not res.crossval.consistent]
    store = force or not refusals
    summary = {"bundle": str(bundle), "cameras": [], "stored": store, "refused": refusals}
    all_files = [f for _, _, _, fs in results for f in fs]
    prov = Provenance(command=command_line(), inputs_sha256=hash_inputs(all_files, {"board": spec.__dict__, "model": model, "k_sigma": k_sigma}))
    for idx, (name, res, lay, _files) in enumerate(results):
        s = _summary(name, res, lay)
        cam, rms, sigma = res.camera, res.calibration.rms_px, res.calibration.sigma
        extra = {}  # the result is K/dist/rms/sigma above; the details are in the session (stored once)
        if st is not None and not fix_intrinsics:  # the joint stereo solve refined these intrinsics: write those
            s["mono"] = {"K": cam.K, "dist": cam.dist, "rms_px": rms, "sigma": sigma}
            cam = st.camera0 if idx == 0 else st.camera1
            sigma = st.sigma0 if idx == 0 else st.sigma1
            rms = st.rms_px
            s.update({"K": cam.K, "dist": cam.dist, "sigma": sigma, "rms_px": rms, "refined_by": f"joint stereo solve over {st.n_pairs} pairs"})
            extra = {"refined_by": s["refined_by"], "mono_rms_px": res.calibration.rms_px}  # the session holds the mono solve
        summary["cameras"].append(s)
        if not store:
            continue
        forced = [r for r in refusals if r.startswith(f"{name}: ")]
        if forced:
            extra["forced"] = [r.split(": ", 1)[1] for r in forced]  # `bundle validate`, the report and `run` show it
        b.set_camera(name, cam, rms_px=rms, sigma=sigma, provenance=prov, extra=extra)
        IntrinsicsSession.from_result(name, res).save(b, f"intrinsics/{name}")
    if st is not None and store:
        b.set_transform(right_camera, camera, st.T_cam1_cam0, method="intrinsics --right (board pairs, " + ("mono intrinsics fixed)" if fix_intrinsics else "jointly with both cameras' intrinsics)"), residual={"rms_px": st.rms_px, "pairs": st.n_pairs, "baseline_m": st.baseline_m}, sigma=st.sigma, provenance=prov)
        StereoSession.from_result(camera, right_camera, st, pair_names).save(b, f"stereo/{camera}_{right_camera}")
        summary["stereo"] = {"T": f"T_{right_camera}_{camera}", "T_cam1_cam0": st.T_cam1_cam0, "baseline_m": st.baseline_m, "sigma": st.sigma, "rms_px": st.rms_px, "pairs": st.n_pairs}
        from radarcal.extrinsics.lidar_camera_chain import refresh_derived  # the other camera's LiDAR / field poses through the pair

        summary["stereo"]["derived"] = refresh_derived(b, command_line())
    if store:
        save_bundle(b)

    def human(s: dict) -> None:
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

    emit(summary, as_json, human)
    if not store:
        raise typer.Exit(1)
