"""``make demo``: a radar-station rig end to end through the foundation (until ``radarcal run`` exists).

What it does, in ``demo_out/`` (printed as it goes):
1. writes the station camera (1280x1024, 8 mm lens, OpenCV radtan-5) as a ROS camera_info file and imports it
   with ``radarcal bundle import`` into ``demo_out/station.yaml``;
2. stores the LiDAR->camera mounting and the LiDAR's pose on the field with ``radarcal bundle set-transform``
   (``x y z roll pitch yaw`` files, as a person would type them);
3. builds a synthetic field scene (28 m x 15 m floor grid + five robots), writes it as a LiDAR PCD and reads it back;
4. projects it into the image with ``bundle.T("cam0", "field")`` (a chained, inverted transform) and
   ``Camera.project``, checks the pixels against ``cv2.projectPoints`` and the rays of ``Camera.unproject``;
5. validates and shows the bundle, and exports the camera for Kalibr-free tools (OpenCV YAML).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

OUT = Path("demo_out")


def _scene(rng: np.random.Generator) -> np.ndarray:
    """Field floor (5 cm grid) and five 0.6 x 0.6 x 0.5 m robots, in the field frame (metres)."""
    xs, ys = np.meshgrid(np.arange(0, 28.0, 0.05), np.arange(0, 15.0, 0.05))
    floor = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    robots = []
    for cx, cy in [(6.0, 4.0), (10.5, 9.0), (14.0, 7.5), (19.0, 3.5), (23.0, 11.0)]:
        p = rng.uniform([-0.3, -0.3, 0.0], [0.3, 0.3, 0.5], size=(3000, 3))
        robots.append(p + [cx, cy, 0.0])
    return np.vstack([floor, *robots])


def main() -> int:
    import cv2

    from radarcal import geometry
    from radarcal.bundle import load_bundle
    from radarcal.camera import Camera
    from radarcal.cli.main import main as cli
    from radarcal.io import export_camera, read_cloud, write_pcd

    OUT.mkdir(exist_ok=True)
    bundle_path = OUT / "station.yaml"
    for old in [bundle_path, *OUT.glob("station.yaml.*.bak")]:
        old.unlink(missing_ok=True)
    print(f"radarcal demo: a radar-station rig through the calibration bundle (output in {OUT}/)\n", flush=True)

    # 1. camera intrinsics from another tool's file
    cam = Camera((1280, 1024), [[1710.4, 0.0, 641.3], [0.0, 1709.8, 508.9], [0.0, 0.0, 1.0]], [-0.1132, 0.1587, 0.00041, -0.00027, -0.0925])
    ros_file = OUT / "cam0_camera_info.yaml"
    ros_file.write_text(export_camera(cam, "ros", "cam0"))
    print(f"1. wrote {ros_file} (ROS camera_info) and imported it:", flush=True)
    if cli(["bundle", "import", str(bundle_path), str(ros_file), "--camera", "cam0"]) != 0:
        return 1

    # 2. mounting and field pose as a person would type them (x y z in m, roll pitch yaw in degrees)
    R_cam_lidar_axes = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # LiDAR x fwd -> camera z fwd
    T_cam0_lidar0_true = geometry.make_T(R_cam_lidar_axes, [0.02, -0.08, -0.05]) @ geometry.T_from_xyz_rpy_deg(0, 0, 0, 0.4, -0.3, 0.8)
    T_field_lidar0_true = geometry.T_from_xyz_rpy_deg(-1.2, 7.5, 2.6, 0.0, 14.0, 0.0)
    mount = OUT / "T_cam0_lidar0.txt"
    mount.write_text(" ".join(f"{v:.12g}" for v in geometry.T_to_xyz_rpy_deg(T_cam0_lidar0_true)) + "\n")
    field = OUT / "T_field_lidar0.txt"
    field.write_text(" ".join(f"{v:.12g}" for v in geometry.T_to_xyz_rpy_deg(T_field_lidar0_true)) + "\n")
    print(f"\n2. stored the LiDAR mounting ({mount}) and the LiDAR's pose on the field ({field}):", flush=True)
    for target, source, f in [("cam0", "lidar0", mount), ("field", "lidar0", field)]:
        if cli(["bundle", "set-transform", str(bundle_path), target, source, str(f)]) != 0:
            return 1

    # 3. a synthetic scan in the LiDAR frame, through a PCD file
    rng = np.random.default_rng(0)
    p_field = _scene(rng)
    p_lidar = geometry.transform_points(geometry.invert_T(T_field_lidar0_true), p_field)
    pcd = OUT / "scan.pcd"
    write_pcd(pcd, p_lidar, intensity=np.where(p_field[:, 2] > 0, 200.0, 20.0))
    cloud = read_cloud(pcd)
    print(f"\n3. wrote {pcd} ({len(p_lidar):,} points, field floor + 5 robots) and read back {len(cloud):,} points", flush=True)

    # 4. project through the bundle
    b = load_bundle(bundle_path)
    T_cam0_field = b.T("cam0", "field")  # cam0 <- lidar0 <- field: one stored edge, one inverted
    chain_err = np.abs(T_cam0_field - T_cam0_lidar0_true @ geometry.invert_T(T_field_lidar0_true)).max()
    camera = b.camera("cam0")
    uv, valid, depth = camera.project_from(b.T("cam0", "lidar0"), cloud.points.astype(float))
    inside = valid & camera.in_image(uv)
    ref, _ = cv2.projectPoints(geometry.transform_points(b.T("cam0", "lidar0"), cloud.points.astype(float))[inside].reshape(-1, 1, 3),
                               np.zeros(3), np.zeros(3), camera.K, camera.dist)
    cv_diff = np.abs(ref.reshape(-1, 2) - uv[inside]).max()
    rays = camera.unproject(uv[inside])
    uv_back, _ = camera.project(rays)
    ray_err = np.abs(uv_back - uv[inside]).max()
    robots = inside & (cloud.intensity > 100)
    print("\n4. projected the scan into cam0 through the bundle:")
    print(f"   T_cam0_field chained from T_cam0_lidar0 and inverted T_field_lidar0: max |diff| vs hand-composed = {chain_err:.1e}")
    print(f"   {inside.sum():,} of {len(uv):,} points land in the 1280x1024 image ({robots.sum():,} on robots), depth {depth[inside].min():.1f}..{depth[inside].max():.1f} m")
    print(f"   max |Camera.project - cv2.projectPoints| = {cv_diff:.1e} px;  unproject->project round trip = {ray_err:.1e} px", flush=True)

    # 5. validate / show / export
    print("\n5. the bundle:", flush=True)
    if cli(["bundle", "validate", str(bundle_path)]) != 0 or cli(["bundle", "show", str(bundle_path)]) != 0:
        return 1
    opencv_file = OUT / "cam0_opencv.yaml"
    if cli(["bundle", "export", str(bundle_path), "--camera", "cam0", "--format", "opencv", "-o", str(opencv_file)]) != 0:
        return 1
    ok = chain_err < 1e-9 and cv_diff < 1e-6 and ray_err < 1e-6 and inside.sum() > 1000 and robots.sum() > 100
    print(f"\ndemo {'OK' if ok else 'FAILED'}: bundle {bundle_path}, camera export {opencv_file}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
