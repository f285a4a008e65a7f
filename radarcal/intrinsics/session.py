"""Session files of ``radarcal intrinsics``: :class:`IntrinsicsSession` (one camera) and :class:`StereoSession` (a pair).

Pixels are px with centres at integer coordinates; ``residuals`` = observed - projected. The camera's result (K, dist,
RMS, σ) lives in the bundle; the session keeps the observations and diagnostics the report draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radarcal.sessions import SessionRecord

__all__ = ["IntrinsicsSession", "StereoSession"]


@dataclass
class IntrinsicsSession(SessionRecord):
    KIND = "intrinsics"
    PATH_FIELDS = ("names",)  # the input files

    # every input, in order, and why it was not used ("used" otherwise)
    names: np.ndarray | None = None  # (I,) str
    status: np.ndarray | None = None  # (I,) str
    view_index: np.ndarray | None = None  # (V,) input index of each solved view
    # per corner of the solved views
    corner_view: np.ndarray | None = None  # (N,) solved-view index
    corner_ids: np.ndarray | None = None  # (N,)
    corners_uv: np.ndarray | None = None  # (N,2) px
    object_points: np.ndarray | None = None  # (N,3) board frame, m
    residuals: np.ndarray | None = None  # (N,2) px
    inliers: np.ndarray | None = None  # (N,) bool
    # per solved view
    rvecs: np.ndarray | None = None
    tvecs: np.ndarray | None = None
    view_used: np.ndarray | None = None  # (V,) bool: kept by the outlier rejection
    view_rms_px: np.ndarray | None = None  # (V,) RMS of the view's inlier residuals
    view_edge_width_px: np.ndarray | None = None
    descriptors: np.ndarray | None = None  # (V,4) pose descriptors used for novelty
    # the camera this session solved (before any joint stereo refinement)
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    image_size: np.ndarray | None = None  # (2,) width, height
    param_names: np.ndarray | None = None
    cov_intrinsics: np.ndarray | None = None
    coverage_grid: np.ndarray | None = None
    uncertainty_u: np.ndarray | None = None  # grid columns (px)
    uncertainty_v: np.ndarray | None = None  # grid rows (px)
    uncertainty_sigma_px: np.ndarray | None = None  # (ny, nx) worst-direction projection σ
    uncertainty_valid: np.ndarray | None = None
    crossval_u: np.ndarray | None = None
    crossval_v: np.ndarray | None = None
    crossval_diff_px: np.ndarray | None = None
    crossval_sigma_px: np.ndarray | None = None
    # metadata
    camera: str = ""  # the bundle's camera name
    camera_model: str = ""  # Camera.model of K/dist: "pinhole" or "fisheye"
    model: str = ""  # the distortion model solved (radtan5, fisheye4, ...)
    rms_px: float | None = None
    noise_px: float | None = None  # estimated per-coordinate corner noise
    uncertainty_threshold_px: float | None = None  # σ below which the uncertainty map is "valid"
    board: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    @classmethod
    def from_result(cls, camera_name: str, res) -> "IntrinsicsSession":
        """From a :class:`radarcal.intrinsics.pipeline.IntrinsicsResult`."""
        from radarcal.board import object_points

        cal = res.calibration
        det = [res.detections[i] for i in res.view_index]
        obj = object_points(res.board)
        s = cls(
            names=np.array(res.names, dtype=str),
            status=np.array(res.status, dtype=str),
            view_index=np.array(res.view_index, int),
            corner_view=np.concatenate([np.full(len(d.ids), k) for k, d in enumerate(det)]),
            corner_ids=np.concatenate([d.ids for d in det]),
            corners_uv=np.concatenate([d.uv for d in det]),
            object_points=np.concatenate([obj[d.ids] for d in det]),
            residuals=np.concatenate(cal.residuals),
            inliers=np.concatenate(cal.inliers),
            rvecs=cal.rvecs,
            tvecs=cal.tvecs,
            view_used=cal.view_used,
            view_rms_px=cal.view_rms(),
            view_edge_width_px=np.array([d.edge_width_px for d in det]),
            descriptors=res.descriptors,
            K=cal.camera.K,
            dist=cal.camera.dist,
            image_size=np.array(cal.camera.image_size),
            param_names=np.array(cal.param_names, dtype=str),
            cov_intrinsics=cal.cov,
            coverage_grid=res.coverage.grid,
            uncertainty_u=res.uncertainty.u,
            uncertainty_v=res.uncertainty.v,
            uncertainty_sigma_px=res.uncertainty.sigma_px,
            uncertainty_valid=res.uncertainty.valid,
            camera=camera_name,
            camera_model=cal.camera.model,
            model=cal.model,
            rms_px=float(cal.rms_px),
            noise_px=float(cal.noise_px),
            uncertainty_threshold_px=float(res.uncertainty.threshold_px),
            board=dict(res.board.__dict__),
            warnings=[str(w) for w in res.warnings],
        )
        if res.crossval is not None:
            cv = res.crossval
            s.crossval_u, s.crossval_v, s.crossval_diff_px, s.crossval_sigma_px = cv.u, cv.v, cv.diff_px, cv.sigma_px
        return s


@dataclass
class StereoSession(SessionRecord):
    KIND = "stereo"

    pair_names: np.ndarray | None = None  # (P,2) str: left / right image of each pair
    T_cam1_cam0: np.ndarray | None = None  # (4,4)
    rvecs_cam0: np.ndarray | None = None
    tvecs_cam0: np.ndarray | None = None
    residuals0: np.ndarray | None = None  # (N,2) px, camera 0
    residuals1: np.ndarray | None = None  # (N,2) px, camera 1
    inliers: np.ndarray | None = None  # (N,) bool
    pair_of_corner: np.ndarray | None = None  # (N,) pair index
    camera0: str = ""
    camera1: str = ""

    @classmethod
    def from_result(cls, camera0: str, camera1: str, st, pair_names) -> "StereoSession":
        """From a :class:`radarcal.intrinsics.stereo` result."""
        return cls(
            pair_names=np.array(pair_names, dtype=str),
            T_cam1_cam0=st.T_cam1_cam0,
            rvecs_cam0=st.rvecs_cam0,
            tvecs_cam0=st.tvecs_cam0,
            residuals0=np.concatenate(st.residuals0),
            residuals1=np.concatenate(st.residuals1),
            inliers=np.concatenate(st.inliers),
            pair_of_corner=np.concatenate([np.full(len(r), k) for k, r in enumerate(st.residuals0)]),
            camera0=camera0,
            camera1=camera1,
        )
