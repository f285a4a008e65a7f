"""``calibrate(...) -> IntrinsicsRun``: the whole of ``radarcal intrinsics`` between reading the views and printing.

One or two cameras' views (:class:`radarcal.intrinsics.collect.CameraViews`) -> per camera
:func:`radarcal.intrinsics.pipeline.run_intrinsics` (screening, solve, outliers, σ, cross-validation, uncertainty)
-> with a right camera the joint stereo solve ``T_cam1_cam0`` over the synchronised pairs -> the refusals of the
checks (an INCONSISTENT cross-validation) -> :meth:`IntrinsicsRun.summary` (what the CLI prints or emits as JSON) and
:meth:`IntrinsicsRun.store` (cameras, transform and session files into the bundle). Errors a user can fix are
:class:`radarcal.errors.InputError` naming the input.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal.board import BoardSpec, object_points
from radarcal.errors import InputError
from radarcal.intrinsics.collect import CameraViews, diagnose
from radarcal.intrinsics.detect import normalise_order
from radarcal.intrinsics.pipeline import IntrinsicsResult, NotEnoughViews, run_intrinsics
from radarcal.intrinsics.solve import MODELS, SolveError
from radarcal.intrinsics.stereo import StereoResult, pair_by_name, stereo_calibrate

__all__ = ["IntrinsicsOptions", "CameraViews", "IntrinsicsRun", "calibrate", "solve_views", "stereo_pairs"]


@dataclass
class IntrinsicsOptions:
    model: str = "pinhole5"  # "auto" or one of radarcal.intrinsics.solve.MODELS
    crossval: bool = True  # split-halves cross-validation
    novelty: float = 0.0  # ROS novelty gate for still images (0 = keep all)
    k_sigma: float = 4.0  # corner outlier threshold in σ
    joint_stereo: bool = True  # refine both cameras' intrinsics with T_cam1_cam0 (False: keep the mono ones)

    def __post_init__(self) -> None:
        if self.model != "auto" and self.model not in MODELS:
            raise InputError("--model", f"expected auto or one of {', '.join(MODELS)}, got {self.model!r}")


def _where(files: list[Path]) -> Path | str:
    """The input to name in an error: the one file, or the folder of several."""
    if not files:
        return "SOURCE"
    return files[0] if len(files) == 1 else files[0].parent


def solve_views(cam: CameraViews, o: IntrinsicsOptions) -> IntrinsicsResult:
    """:func:`run_intrinsics` on one camera's views; too few usable views or a failed solve become an
    ``InputError`` that says how many boards were found and, from a look at the rejected images, why (a wrong
    ``--cols/--rows/--dict`` finds a stray board or none)."""
    dets = [v.detection for v in cam.views]
    try:
        return run_intrinsics([v.name for v in cam.views], dets, cam.board, [v.error for v in cam.views], model=o.model, crossval=o.crossval, novelty=o.novelty, k_sigma=o.k_sigma)
    except NotEnoughViews as e:
        failed = [v for v in cam.views if not (v.detection and v.detection.ok)]
        n_board = len(cam.views) - len(failed)
        detail = "; ".join(sorted({v.error or (v.detection.reason if v.detection else "") for v in failed} - {""}))[:300]
        without = [Path(v.name) for v in failed if Path(v.name).is_file()]
        hint = diagnose(without, cam.board) if without else None
        what = f"{cam.board.cols}x{cam.board.rows} {'chessboard' if cam.board.kind == 'chessboard' else 'ChArUco board'}"
        if n_board == 0:
            msg = f"no {what} found in any of {len(cam.views)} inputs" + (f": {hint}" if hint else f" ({detail})" if detail else "")
        else:
            msg = f"{e}: the {what} was found in {n_board} of {len(cam.views)} inputs" + (f"; {hint}" if hint else f"; rejected: {detail}")
        raise InputError(_where(cam.files), msg) from None
    except SolveError as e:
        raise InputError(_where(cam.files), str(e)) from None


def stereo_pairs(res0: IntrinsicsResult, res1: IntrinsicsResult, board: BoardSpec) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], list[tuple[str, str]]]:
    """The synchronised pairs (paired by the number in the file names) whose views both mono solves used: object
    points and both images' corners (chessboard corners of the right image in the left's order; ChArUco: the ids
    both saw, at least 6), and the pairs' names."""
    used0 = {res0.names[i] for k, i in enumerate(res0.view_index) if res0.calibration.view_used[k]}
    used1 = {res1.names[i] for k, i in enumerate(res1.view_index) if res1.calibration.view_used[k]}
    obj_all = object_points(board)
    objs, q0, q1, names = [], [], [], []
    for i, j in pair_by_name(res0.names, res1.names):
        a, b = res0.names[i], res1.names[j]
        if a not in used0 or b not in used1:
            continue
        d0, d1 = res0.detections[i], res1.detections[j]
        if board.kind == "chessboard":
            objs.append(obj_all)
            q0.append(d0.uv)
            q1.append(normalise_order(d1.uv, board.grid_shape, reference=d0.uv))
        else:
            common, i0, i1 = np.intersect1d(d0.ids, d1.ids, return_indices=True)
            if len(common) < 6:
                continue
            objs.append(obj_all[common])
            q0.append(d0.uv[i0])
            q1.append(d1.uv[i1])
        names.append((a, b))
    return objs, q0, q1, names


def _uncertainty_summary(unc) -> dict:
    """What the projection-σ map says: the centre, median and 90th percentile (px), where it is within 2x the
    centre's (what this data set can give), and where it is below the per-corner noise (``valid_fraction``)."""
    sig = np.asarray(unc.sigma_px, float)
    finite = sig[np.isfinite(sig)]
    centre = unc.at_centre()
    return {"centre_px": centre, "median_px": float(np.median(finite)) if finite.size else float("nan"), "p90_px": float(np.percentile(finite, 90)) if finite.size else float("nan"),
            "within_2x_centre_fraction": float(np.mean(np.isfinite(sig) & (sig <= 2 * centre))), "valid_fraction": unc.valid_fraction, "threshold_px": unc.threshold_px,
            "valid_means": "projection σ below the per-corner noise σ (threshold_px)"}


def _camera_summary(name: str, res: IntrinsicsResult, layout_info: dict) -> dict:
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
        s["charuco_layout"] = {k: layout_info.get(k) for k in ("legacy", "corners_new_layout", "corners_legacy_layout")}
    return s


@dataclass
class IntrinsicsRun:
    """The result of :func:`calibrate`: per camera its inputs and :class:`IntrinsicsResult`, the stereo solve (or None)."""

    cameras: list[tuple[CameraViews, IntrinsicsResult]]
    stereo: StereoResult | None
    pair_names: list[tuple[str, str]]
    options: IntrinsicsOptions
    derived: object = None  # what store() re-derived through the stereo pair (radarcal.extrinsics.lidar_camera_chain.refresh_derived)

    @property
    def refusals(self) -> list[str]:
        """What the checks refuse to store without ``--force``: an INCONSISTENT cross-validation."""
        return [f"{cam.name}: cross-validation INCONSISTENT (halves differ {res.crossval.diff_median_px:.2f} px vs σ {res.crossval.sigma_median_px:.2f} px)"
                for cam, res in self.cameras if res.crossval is not None and not res.crossval.consistent]

    def _written(self, idx: int) -> tuple:
        """(camera, rms, sigma) to write for camera ``idx``: the joint stereo solve's when it refined them."""
        res = self.cameras[idx][1]
        st = self.stereo
        if st is not None and self.options.joint_stereo:
            return (st.camera0, st.rms_px, st.sigma0) if idx == 0 else (st.camera1, st.rms_px, st.sigma1)
        return res.camera, res.calibration.rms_px, res.calibration.sigma

    def summary(self) -> dict:
        out = {"cameras": [], "refused": self.refusals}
        for idx, (cam, res) in enumerate(self.cameras):
            s = _camera_summary(cam.name, res, cam.layout_info)
            if self.stereo is not None and self.options.joint_stereo:
                c, rms, sigma = self._written(idx)
                s["mono"] = {"K": res.camera.K, "dist": res.camera.dist, "rms_px": res.calibration.rms_px, "sigma": res.calibration.sigma}
                s.update({"K": c.K, "dist": c.dist, "sigma": sigma, "rms_px": rms, "refined_by": f"joint stereo solve over {self.stereo.n_pairs} pairs"})
            out["cameras"].append(s)
        if self.stereo is not None:
            st, (c0, c1) = self.stereo, (self.cameras[0][0].name, self.cameras[1][0].name)
            out["stereo"] = {"T": f"T_{c1}_{c0}", "T_cam1_cam0": st.T_cam1_cam0, "baseline_m": st.baseline_m, "sigma": st.sigma, "rms_px": st.rms_px, "pairs": st.n_pairs}
            if self.derived is not None:
                out["stereo"]["derived"] = self.derived
        return out

    def store(self, b, command: str) -> None:
        """Cameras (K, dist, RMS, σ; ``forced`` when stored over a refusal), ``T_cam1_cam0`` and the session files
        into the loaded bundle ``b`` (the caller saves it)."""
        from radarcal.bundle import Provenance, hash_inputs
        from radarcal.intrinsics.session import IntrinsicsSession, StereoSession

        o = self.options
        files = [f for cam, _ in self.cameras for f in cam.files]
        board = self.cameras[0][0].board
        prov = Provenance(command=command, inputs_sha256=hash_inputs(files, {"board": board.__dict__, "model": o.model, "k_sigma": o.k_sigma}))
        refusals = self.refusals
        for idx, (cam, res) in enumerate(self.cameras):
            c, rms, sigma = self._written(idx)
            extra = {}  # the result is K/dist/rms/sigma; the details are in the session (stored once)
            if c is not res.camera:
                extra = {"refined_by": f"joint stereo solve over {self.stereo.n_pairs} pairs", "mono_rms_px": res.calibration.rms_px}
            forced = [r.split(": ", 1)[1] for r in refusals if r.startswith(f"{cam.name}: ")]
            if forced:
                extra["forced"] = forced  # `bundle validate`, the report and `run` show it
            b.set_camera(cam.name, c, rms_px=rms, sigma=sigma, provenance=prov, extra=extra)
            IntrinsicsSession.from_result(cam.name, res).save(b, f"intrinsics/{cam.name}")
        if self.stereo is not None:
            st, c0, c1 = self.stereo, self.cameras[0][0].name, self.cameras[1][0].name
            how = "jointly with both cameras' intrinsics)" if o.joint_stereo else "mono intrinsics fixed)"
            b.set_transform(c1, c0, st.T_cam1_cam0, method="intrinsics --right (board pairs, " + how,
                            residual={"rms_px": st.rms_px, "pairs": st.n_pairs, "baseline_m": st.baseline_m}, sigma=st.sigma, provenance=prov)
            StereoSession.from_result(c0, c1, st, self.pair_names).save(b, f"stereo/{c0}_{c1}")
            from radarcal.extrinsics.lidar_camera_chain import refresh_derived  # the other camera's LiDAR / field poses through the pair

            self.derived = refresh_derived(b, command)


def calibrate(left: CameraViews, right: CameraViews | None = None, options: IntrinsicsOptions | None = None) -> IntrinsicsRun:
    """Intrinsics of ``left`` (and ``right``), and with ``right`` the stereo ``T_cam1_cam0`` (cam1 = right)."""
    o = options or IntrinsicsOptions()
    cams = [(left, solve_views(left, o))]
    st, names = None, []
    if right is not None:
        cams.append((right, solve_views(right, o)))
        objs, q0, q1, names = stereo_pairs(cams[0][1], cams[1][1], left.board)
        if not names:
            raise InputError("--right", "no synchronised pair has the board in both images (pairing is by the number in the file names)")
        st = stereo_calibrate(cams[0][1].camera, cams[1][1].camera, objs, q0, q1, refine_intrinsics=o.joint_stereo)
    return IntrinsicsRun(cams, st, names, o)
