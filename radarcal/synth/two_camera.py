"""Ground-truth two-camera radar stations: what ``field-pnp --camera``, ``lidar-camera --camera`` and the camera
cross-check (:mod:`radarcal.pnp.cross_check`) are measured on. Two independent families:

* ``family=1`` ("station"): the built-in schematic field, the red station of :func:`radarcal.synth.field.default_rig`
  (wide 1100 px camera ``cam0`` + its LiDAR ``lidar0``) and a tele camera ``cam1`` (2500 px, ≈ 12 mm on 4.8 µm
  pixels) 12-20 cm beside it, aimed at the far half. Link between the cameras: both LiDAR extrinsics (PnP on
  LiDAR-image correspondences). Clicks: Gaussian.
* ``family=2`` ("random field"): a field drawn per seed (20-32 m x 12-18 m, 3-6 raised blocks, 10-16 landmarks on
  posts and block corners), the station at either end at 2-4 m height, cameras with drawn intrinsics (640x512 or
  1280x1024, rational or radtan distortion; cam1 1.6-2.6x the focal length of cam0), **no LiDAR**: the link is a
  stereo ``T_cam1_cam0`` (20-60 cm baseline) with the σ of a stereo calibration. Clicks: integer pixels (rounded)
  plus heavy-tailed noise.

:func:`write_two_camera_scene` writes the files a user has: ``bundle.yaml`` (intrinsics, field, the stereo pair for
family 2), ``picks_cam0.csv`` / ``picks_cam1.csv`` (``name,u,v``), ``corners_cam0.csv`` / ``corners_cam1.csv``
(``x,y,z,u,v``, family 1) and ``truth.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera

__all__ = ["TwoCameraScene", "two_camera_scene", "noisy_picks", "lidar_correspondences", "write_two_camera_scene"]

_R_BODY_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera axes in a body frame (x fwd, y left, z up)


@dataclass
class TwoCameraScene:
    family: int
    seed: int
    field: object  # radarcal.field.FieldModel
    cameras: dict  # name -> Camera
    T_field_cam: dict  # name -> 4x4
    T_cam_lidar: dict | None  # name -> 4x4 (family 1), None (family 2: no LiDAR)

    @property
    def T_cam1_cam0(self) -> np.ndarray:
        return geometry.invert_T(self.T_field_cam["cam1"]) @ self.T_field_cam["cam0"]

    def T_cam_field(self, name: str) -> np.ndarray:
        return geometry.invert_T(self.T_field_cam[name])

    def visible_landmarks(self, name: str, margin_px: float = 10.0) -> tuple[list[str], np.ndarray]:
        """Landmarks in camera ``name``'s image (exact pixels), in the field's order."""
        cam = self.cameras[name]
        names = list(self.field.landmarks)
        uv, ok, _ = cam.project_from(self.T_cam_field(name), self.field.landmark_array(names))
        ok &= cam.in_image(uv, margin=margin_px)
        return [n for n, k in zip(names, ok) if k], uv[ok]


def _look_at(pos: np.ndarray, target: np.ndarray, roll_deg: float = 0.0) -> np.ndarray:
    fwd = target - pos
    yaw = np.degrees(np.arctan2(fwd[1], fwd[0]))
    pitch = np.degrees(np.arctan2(-fwd[2], np.linalg.norm(fwd[:2])))
    return geometry.make_T(geometry.rpy_deg_to_R(roll_deg, pitch, yaw) @ _R_BODY_CAM, pos)


def _family1(seed: int) -> TwoCameraScene:
    from radarcal.field import load_field
    from radarcal.synth.field import default_rig

    rng = np.random.default_rng(seed)
    fm = load_field("rmuc2024")
    rig = default_rig(fm, rng)
    tele = Camera((1280, 1024), np.array([[2500.0, 0, 639.5 + rng.uniform(-8, 8)], [0, 2500.0, 511.5 + rng.uniform(-8, 8)], [0, 0, 1]]),
                  np.array([rng.uniform(-0.05, 0.0), 0.0, 0.0, 0.0, 0.0]))
    C0 = rig.T_field_cam[:3, 3]
    right = rig.T_field_cam[:3, 0]  # cam0's x axis (right) in the field: cam1 sits beside it
    C1 = C0 + right * rng.uniform(0.12, 0.2) + np.array([0, 0, rng.uniform(-0.05, 0.05)])
    T_field_cam1 = _look_at(C1, np.array([rng.uniform(19, 22), rng.uniform(6, 9), 0.6]), rng.uniform(-0.5, 0.5))
    T_field_lidar = rig.T_field_lidar
    cams = {"cam0": rig.camera, "cam1": tele}
    Tf = {"cam0": rig.T_field_cam, "cam1": T_field_cam1}
    return TwoCameraScene(1, seed, fm, cams, Tf, {k: geometry.invert_T(Tf[k]) @ T_field_lidar for k in cams})


def _random_field(rng: np.random.Generator):
    from radarcal.field import field_from_dict

    L, W = rng.uniform(20, 32), rng.uniform(12, 18)
    areas, landmarks = [], {}
    for i in range(int(rng.integers(3, 7))):
        cx, cy = rng.uniform(0.25, 0.85) * L, rng.uniform(0.15, 0.85) * W
        hx, hy, z = rng.uniform(0.8, 2.5), rng.uniform(0.8, 2.0), rng.uniform(0.2, 1.0)
        poly = [[cx - hx, cy - hy], [cx + hx, cy - hy], [cx + hx, cy + hy], [cx - hx, cy + hy]]
        areas.append({"name": f"block{i}", "polygon": poly, "z": float(z)})
        for j in rng.choice(4, size=2, replace=False):
            landmarks[f"block{i}_corner{j}"] = [poly[j][0], poly[j][1], float(z)]
    for i in range(int(rng.integers(6, 11))):  # posts: thin markers of 0.5-2.5 m
        landmarks[f"post{i}"] = [float(rng.uniform(0.3, 1.0) * L), float(rng.uniform(0.05, 0.95) * W), float(rng.uniform(0.5, 2.5))]
    return field_from_dict({"name": "random_field", "size": [float(L), float(W)], "landmarks": landmarks, "areas": areas})


def _family2(seed: int) -> TwoCameraScene:
    from radarcal.synth.lidar_camera_family2 import family2_camera

    rng = np.random.default_rng(10_000 + seed)
    fm = _random_field(rng)
    L, W = fm.size
    res = "640x512" if rng.random() < 0.4 else "1280x1024"
    wide = family2_camera(rng, res)
    k = rng.uniform(1.6, 2.6)
    K = wide.K.copy()
    K[:2, :2] *= k
    tele = Camera(wide.image_size, K, np.concatenate([wide.dist[:2] * 0.3, np.zeros(len(wide.dist) - 2)]))
    pos = np.array([-rng.uniform(0.3, 1.5), rng.uniform(0.3, 0.7) * W, rng.uniform(2.0, 4.0)])
    T0 = _look_at(pos, np.array([0.5 * L, rng.uniform(0.35, 0.65) * W, 0.0]), rng.uniform(-1, 1))
    baseline = rng.uniform(0.2, 0.6)
    C1 = pos + T0[:3, 0] * baseline + T0[:3, 1] * rng.uniform(-0.05, 0.05)
    T1 = _look_at(C1, np.array([rng.uniform(0.6, 0.8) * L, rng.uniform(0.35, 0.65) * W, 0.5]), rng.uniform(-1, 1))
    Tf = {"cam0": T0, "cam1": T1}
    if rng.random() < 0.5:  # the station at the other end: turn the field about its centre
        flip = np.array([[-1.0, 0, 0, L], [0, -1.0, 0, W], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
        Tf = {n: flip @ T for n, T in Tf.items()}
    return TwoCameraScene(2, seed, fm, {"cam0": wide, "cam1": tele}, Tf, None)


def two_camera_scene(family: int = 1, seed: int = 0) -> TwoCameraScene:
    """A two-camera station with known truth (module docstring); deterministic in ``seed``."""
    if family == 1:
        return _family1(seed)
    if family == 2:
        return _family2(seed)
    raise ValueError(f"family: expected 1 or 2, got {family!r}")


def noisy_picks(scene: TwoCameraScene, name: str, rng: np.random.Generator, sigma_px: float = 1.0) -> tuple[list[str], np.ndarray]:
    """The visible landmarks as clicked: family 1 Gaussian σ px; family 2 rounded to integer pixels plus Student-t
    (3 dof) noise scaled to σ."""
    names, uv = scene.visible_landmarks(name)
    if scene.family == 1:
        return names, uv + rng.normal(0, sigma_px, uv.shape)
    return names, np.rint(uv) + sigma_px * rng.standard_t(3, uv.shape) / np.sqrt(3.0)


def lidar_correspondences(scene: TwoCameraScene, name: str, rng: np.random.Generator, n: int = 12, sigma_px: float = 1.0, range_sigma_m: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Family 1: ``n`` LiDAR points (6-25 m, in camera ``name``'s view; 2 cm range noise along the LiDAR ray) and their
    clicked pixels (σ px): a ``lidar-camera --corners`` file's content."""
    cam, T = scene.cameras[name], scene.T_cam_lidar[name]
    w, h = cam.image_size
    uv = np.column_stack([rng.uniform(0.08, 0.92, n) * w, rng.uniform(0.08, 0.92, n) * h])
    rays = cam.unproject(uv)
    p_cam = rays / rays[:, 2:3] * rng.uniform(6, 25, (n, 1))
    p_lidar = geometry.transform_points(geometry.invert_T(T), p_cam)
    r = np.linalg.norm(p_lidar, axis=1, keepdims=True)
    p_lidar = p_lidar * (1 + rng.normal(0, range_sigma_m, (n, 1)) / r)
    return p_lidar, uv + rng.normal(0, sigma_px, uv.shape)


def write_two_camera_scene(scene: TwoCameraScene, out_dir: str | Path, click_sigma_px: float = 1.0, stereo_sigma: tuple[float, float] = (0.02, 0.0005)) -> dict:
    """Write the scene's user files (module docstring) into ``out_dir``; returns their paths. Noise is seeded by the
    scene's seed. ``stereo_sigma``: (deg, m) of the family-2 stereo pair as ``radarcal intrinsics --right`` gives it."""
    from radarcal.bundle import Bundle, Provenance, save_bundle

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([scene.family, scene.seed, 7])
    b = Bundle(path=out / "bundle.yaml")
    prov = Provenance(command=f"radarcal.synth.two_camera family {scene.family} seed {scene.seed}")
    for n, cam in scene.cameras.items():
        b.set_camera(n, cam, provenance=prov)
    b.field_model = scene.field.to_dict()
    files = {"bundle": out / "bundle.yaml"}
    truth = {"family": scene.family, "seed": scene.seed, "T_field_cam": {n: T.tolist() for n, T in scene.T_field_cam.items()}, "T_cam1_cam0": scene.T_cam1_cam0.tolist()}
    for n in scene.cameras:
        names, uv = noisy_picks(scene, n, rng, click_sigma_px)
        p = out / f"picks_{n}.csv"
        p.write_text("name,u,v\n" + "".join(f"{m},{float(u)!r},{float(v)!r}\n" for m, (u, v) in zip(names, uv)))
        files[f"picks_{n}"] = p
        if scene.T_cam_lidar is not None:
            P, U = lidar_correspondences(scene, n, rng, sigma_px=click_sigma_px)
            c = out / f"corners_{n}.csv"
            c.write_text("x,y,z,u,v\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in np.column_stack([P, U])))
            files[f"corners_{n}"] = c
    if scene.T_cam_lidar is not None:
        b.set_sensor("lidar0", type="lidar")
        truth["T_cam_lidar"] = {n: T.tolist() for n, T in scene.T_cam_lidar.items()}
    else:
        dev = geometry.T_from_rotvec(np.radians(rng.normal(0, stereo_sigma[0], 3)), rng.normal(0, stereo_sigma[1], 3))
        b.set_transform("cam1", "cam0", dev @ scene.T_cam1_cam0, method="intrinsics --right (generated: truth + stereo σ)", provenance=prov)
    save_bundle(b)
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    files["truth"] = out / "truth.json"
    return files
