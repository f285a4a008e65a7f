"""``radarcal field-pnp`` as one call: ``calibrate(bundle, camera, field, picks, options) -> FieldPnPCalibration``
(pose from the picks, error map, depth source) and :meth:`FieldPnPCalibration.store` (``T_<camera>_field``, the
field model, the session file, the transforms derived through a stereo pair, then the camera cross-check).

Frames: ``T_cam_field`` maps field points (origin at a corner, x along the long side, z up; m) into the camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError

__all__ = ["FieldPnPOptions", "FieldPnPCalibration", "resolve_field", "calibrate"]


@dataclass
class FieldPnPOptions:
    click_sigma: float = 1.0  # px, assumed click noise (σ and the error map)
    pixel_sigma: float = 1.0  # px, detection noise in the error map
    range_sigma: float = 0.02  # m, LiDAR range noise in the error map
    max_rms: float = 5.0  # px: reject the pose above this reprojection RMS
    ransac_px: float = 8.0  # px: outlier threshold with more than 4 picks
    grid: float = 1.0  # m, error-map cell
    depth: str = "auto"  # auto | lidar | ground: the printed map's depth source
    lidar: str | None = None  # LiDAR sensor name (default: any LiDAR chained to the camera)

    def pnp(self):
        from radarcal.pnp.field_pnp import PnPOptions

        for opt, v in (("--click-sigma", self.click_sigma), ("--max-rms", self.max_rms), ("--ransac-px", self.ransac_px), ("--grid", self.grid)):
            if not v > 0:
                raise InputError(opt, f"must be > 0, got {v}")
        return PnPOptions(click_sigma_px=self.click_sigma, max_rms_px=self.max_rms, ransac_threshold_px=self.ransac_px)


def resolve_field(bundle, name: str | None):
    """``(FieldModel, where it came from)``: ``name`` (built-in or file), else the bundle's field, else rmuc2024."""
    from radarcal.field import load_field

    if name is not None:
        return load_field(name), name
    if bundle.field_model:
        fm = bundle.field()
        return fm, f"bundle ({fm.name})"
    return load_field("rmuc2024"), "rmuc2024"


def _depth_source(bundle, camera: str, lidar: str | None) -> str | None:
    """Name of a LiDAR chained to the camera (the runtime's depth source), or None (ground fallback)."""
    names = [lidar] if lidar else [n for n, m in bundle.sensors.items() if m.get("type") == "lidar"]
    return next((n for n in names if n and bundle.has_T(camera, n)), None)


@dataclass
class FieldPnPCalibration:
    camera_name: str
    camera: object  # radarcal.Camera
    field: object  # FieldModel
    field_source: str
    result: object  # radarcal.pnp.field_pnp.FieldPnPResult
    error_map: object  # ErrorMap on options.grid
    error_map_print: object  # the same on >= 2 m cells (the printed table)
    lidar: str | None
    depth_used: str
    picks_file: Path
    options: FieldPnPOptions
    image: Path | None = None
    cross_checks: list = field(default_factory=list)  # PairAgreement of this camera with the others (after store)

    def write_figures(self, error_map_png: Path | None, overlay: Path | None) -> None:
        """The error map PNG and the overlay on the image (before anything is stored: a failure changes nothing)."""
        r, fm, o = self.result, self.field, self.options
        if error_map_png is not None:
            from radarcal.pnp.figures import save_error_map_png

            try:
                save_error_map_png(error_map_png, self.error_map, fm, r.camera_position, r.names,
                                   title=f"{self.camera_name} on {fm.name}: 1σ localisation error for {o.click_sigma:g} px clicks, {o.pixel_sigma:g} px detections")
            except (ValueError, OSError) as e:  # matplotlib: unknown extension; the file system: full, vanished folder
                raise InputError(error_map_png, f"cannot write the error map ({e})") from None
        if overlay is not None:
            import cv2

            from radarcal.io import read_image
            from radarcal.pnp.figures import draw_overlay

            if not cv2.imwrite(str(overlay), draw_overlay(read_image(self.image), self.camera, r.T_cam_field, fm, r.names, r.uv)):
                raise InputError(overlay, "cannot write the overlay image (unknown extension or unwritable folder)")

    def store(self, bundle, bundle_path: Path, command: str) -> list[str]:
        """``T_<camera>_field`` (residuals, σ, provenance), the field model and the session; derived transforms
        refreshed; saved. Then the cross-check with the other cameras (:attr:`cross_checks`). Returns the
        derived-entry changes."""
        from radarcal.bundle import Provenance, hash_inputs, save_bundle
        from radarcal.extrinsics.lidar_camera_chain import refresh_derived
        from radarcal.pnp.cross_check import bundle_cross_checks
        from radarcal.pnp.session import FieldPnPSession

        r, fm, o, em, cam = self.result, self.field, self.options, self.error_map, self.camera_name
        per_point = {n: float(np.linalg.norm(x)) for n, x in zip(r.names, r.residuals_px)}
        inputs = [self.picks_file] + ([self.image] if self.image else [])
        prov = Provenance(command=command, inputs_sha256=hash_inputs(inputs, extra={"field": fm.to_dict(), "click_sigma": o.click_sigma, "max_rms": o.max_rms, "ransac_px": o.ransac_px}))
        residual = {"rms_px": r.rms_px, "per_point_px": per_point, "n_picks": len(r.names), "n_inliers": int(r.inliers.sum()), "outliers": [n for n, k in zip(r.names, r.inliers) if not k]}
        bundle.set_transform(cam, "field", r.T_cam_field, method=f"field-pnp ({r.method}) on {fm.name}", residual=residual, sigma=r.sigma, provenance=prov)
        bundle.field_model = fm.to_dict()
        FieldPnPSession(
            names=np.array(r.names, dtype=str), uv=r.uv, p_field=r.p_field, residuals_px=r.residuals_px, inliers=r.inliers, T_cam_field=r.T_cam_field,
            cov_pose=r.cov_pose, camera_position=r.camera_position, grid_x=em.xs, grid_y=em.ys, sigma_lidar=em.sigma_lidar, sigma_ground=em.sigma_ground,
            field=fm.name, camera=cam, click_sigma_px=o.click_sigma, pixel_sigma_px=o.pixel_sigma, range_sigma_m=o.range_sigma, rms_px=float(r.rms_px),
            depth_source=self.depth_used, lidar=self.lidar, image=str(self.image) if self.image else "", picks_file=str(self.picks_file), warnings=list(r.warnings),
        ).save(bundle, f"field_pnp/{cam}")  # fmt: skip
        changes = refresh_derived(bundle, command)
        save_bundle(bundle, bundle_path)
        self.cross_checks = [p for p in bundle_cross_checks(bundle) if cam in (p.camera_a, p.camera_b)]
        return changes

    def summary(self) -> dict:
        r, em, o = self.result, self.error_map, self.options
        per_point = {n: float(np.linalg.norm(x)) for n, x in zip(r.names, r.residuals_px)}
        from radarcal.pnp.cross_check import format_agreement

        return {
            "camera": self.camera_name, "field": self.field.name, "field_source": self.field_source,
            "picks": [{"name": n, "u": float(u[0]), "v": float(u[1]), "residual_px": per_point[n], "inlier": bool(k)} for n, u, k in zip(r.names, r.uv, r.inliers)],
            "n_inliers": int(r.inliers.sum()), "rms_px": r.rms_px, "T_cam_field": r.T_cam_field, "camera_position_m": r.camera_position,
            "camera_rpy_deg": geometry.T_to_xyz_rpy_deg(geometry.invert_T(r.T_cam_field))[3:], "sigma": r.sigma, "warnings": r.warnings,
            "lidar": self.lidar, "depth_source": self.depth_used, "click_sigma_px": o.click_sigma, "pixel_sigma_px": o.pixel_sigma,
            "error_map": {"lidar": em.stats("lidar"), "ground": em.stats("ground"), "grid_m": o.grid, "xs": em.xs, "ys": em.ys, "sigma_lidar": em.sigma_lidar, "sigma_ground": em.sigma_ground},
            "cross_check": [{**vars(p), "text": format_agreement(p)} for p in self.cross_checks],
        }  # fmt: skip


def calibrate(bundle, camera: str, fm, field_source: str, names: list[str], uv: np.ndarray, picks_file: Path, options: FieldPnPOptions | None = None,
              T_override: np.ndarray | None = None, image: Path | None = None) -> FieldPnPCalibration:
    """The camera's pose on the field from the picks (InputError naming ``picks_file`` when they do not determine
    one), the error map over the field and the depth source the runtime will use."""
    from radarcal.pnp.error_map import error_map
    from radarcal.pnp.field_pnp import FieldPnPError, solve_field_pnp

    o = options or FieldPnPOptions()
    if o.depth not in ("auto", "lidar", "ground"):
        raise InputError("--depth", f"expected auto, lidar or ground, got {o.depth!r}")
    popt = o.pnp()
    cam = bundle.camera(camera)
    outside = ~cam.in_image(uv, margin=-0.5)
    if np.any(outside):
        raise InputError(picks_file, f"pick {names[int(np.argmax(outside))]} is outside the {cam.width}x{cam.height} image")
    try:
        res = solve_field_pnp(cam, fm.landmark_array(names), uv, names, popt, surface_z=fm.surface_z)
        if T_override is not None:
            from radarcal.pnp.ui import pose_result

            res = pose_result(cam, res, T_override, popt)
    except FieldPnPError as e:
        raise InputError(picks_file, str(e)) from None
    lidar = _depth_source(bundle, camera, o.lidar)
    if o.lidar and lidar is None:
        raise InputError("--lidar", f"no transform chain between {o.lidar!r} and {camera!r} in the bundle")
    used = o.depth if o.depth != "auto" else ("lidar" if lidar else "ground")
    em = error_map(cam, res.T_cam_field, res.cov_pose, fm, step=o.grid, pixel_sigma=o.pixel_sigma, range_sigma=o.range_sigma)
    em_print = em if o.grid >= 2.0 else error_map(cam, res.T_cam_field, res.cov_pose, fm, step=2.0, pixel_sigma=o.pixel_sigma, range_sigma=o.range_sigma)
    return FieldPnPCalibration(camera, cam, fm, field_source, res, em, em_print, lidar, used, Path(picks_file), o, image)
