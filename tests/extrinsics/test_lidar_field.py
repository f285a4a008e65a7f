"""lidar-field registration on clouds ray-cast against the real 2024 mesh (truth known), its verdict both ways and
its degeneracy check."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.lidar_field import LidarFieldOptions, MeshTarget, floor_plane, register_lidar_field
from radarcal.field import field_from_dict, load_field, polygon_field_mesh
from radarcal.io.meshes import read_mesh
from radarcal.synth.lidar_field import LidarFieldSceneConfig, clutter_from, lidar_field_scene, venue_mesh
from tests.conftest import shared_dataset


@pytest.fixture(scope="module")
def mesh24():
    d = shared_dataset("hitsz_rmuc_field_meshes")
    fm = load_field(d / "24_bg2align_fix1.stl")
    return fm, clutter_from(read_mesh(d / "24_bg2filter_fix1.stl"), fm), MeshTarget(fm.mesh)


def _scene(fm, clutter, seed, side="red", points=120_000):
    return lidar_field_scene(fm, LidarFieldSceneConfig(seed=seed, side=side, points=points), clutter=[clutter])


@pytest.mark.slow
@pytest.mark.parametrize("seed,side", [(3, "red"), (4, "blue")])
def test_registers_from_2deg_30cm(mesh24, seed, side):
    fm, clutter, target = mesh24
    sc = _scene(fm, clutter, seed, side)
    assert np.bincount(sc.labels, minlength=4)[2] > 100  # robots are in the cloud (and not in the mesh)
    T0 = geometry.perturb_T(sc.T_field_lidar, 2.0, 0.3, np.random.default_rng(seed))
    r = register_lidar_field(sc.points_lidar, target, T0)
    deg, m = geometry.pose_error(r.T_field_lidar, sc.T_field_lidar)
    assert deg < 0.05 and m < 0.02, (deg, m)
    assert r.verdict == "converged", r.reasons
    # σ is an honest scale of the error: the error is within 5σ on each axis-group
    assert m < 5 * max(np.linalg.norm([r.sigma["x"], r.sigma["y"], r.sigma["z"]]), 1e-3)


def test_cloud_of_another_room_fails(mesh24):
    """A cloud that sees no field (a hall with boxes in it, no field surface): never 'converged'."""
    import open3d as o3d

    fm, _, target = mesh24
    room = venue_mesh((12.0, 8.0), "hall")
    from radarcal.field import _o3d_scene
    from radarcal.synth.lidar_patterns import livox_rosette_dirs

    scene = _o3d_scene(room)
    T = geometry.T_from_xyz_rpy_deg(1.0, 4.0, 2.5, 0, 10, 0)
    d = livox_rosette_dirs(np.arange(60000) / 60000.0) @ T[:3, :3].T
    hit = scene.cast_rays(o3d.core.Tensor(np.hstack([np.broadcast_to(T[:3, 3], d.shape), d]).astype(np.float32)))["t_hit"].numpy()
    ok = np.isfinite(hit)
    pts = (livox_rosette_dirs(np.arange(60000) / 60000.0)[ok] * hit[ok, None]).astype(np.float32)
    r = register_lidar_field(pts, target, geometry.T_from_xyz_rpy_deg(-1.0, 7.5, 2.5, 0, 10, 0), LidarFieldOptions(max_points=4000, restart_points=2000, polish_points=8000))
    assert r.verdict != "converged"


@pytest.mark.slow
def test_wrong_start_is_not_called_converged(mesh24):
    """Started 20° and 3 m off (far outside the basin), the result is either right or not 'converged'."""
    fm, clutter, target = mesh24
    sc = _scene(fm, clutter, 7)
    T0 = geometry.perturb_T(sc.T_field_lidar, 20.0, 3.0, np.random.default_rng(0))
    r = register_lidar_field(sc.points_lidar, target, T0, LidarFieldOptions(restarts=False))
    deg, m = geometry.pose_error(r.T_field_lidar, sc.T_field_lidar)
    assert r.verdict != "converged" or (deg < 0.1 and m < 0.05), (r.verdict, deg, m)


def test_flat_floor_is_degenerate_and_names_x_y_yaw():
    """A field that is a plane: z, roll and pitch are observed, x, y and yaw are not — the check must say so."""
    flat = field_from_dict({"name": "flat", "size": [28, 15], "landmarks": {"o": [0, 0, 0]}})
    target = MeshTarget(polygon_field_mesh(flat, margin=20.0))
    fm_like = flat
    fm_like.mesh = polygon_field_mesh(flat, margin=20.0)
    sc = lidar_field_scene(fm_like, LidarFieldSceneConfig(seed=1, points=60_000, robots=0, venue="open"))
    far = np.linalg.norm(sc.points_lidar, axis=1) < 20  # floor only (no walls)
    T0 = geometry.perturb_T(sc.T_field_lidar, 1.0, 0.1, np.random.default_rng(1))
    r = register_lidar_field(sc.points_lidar[far & (sc.labels == 0)], target, T0)
    assert r.verdict in ("degenerate", "ambiguous")
    assert {"x", "y", "yaw"} <= set(r.weak_directions) or r.verdict == "ambiguous"
    assert not {"z", "roll", "pitch"} & set(r.weak_directions)


def test_floor_plane_gives_height_and_tilt(mesh24):
    fm, clutter, _ = mesh24
    sc = _scene(fm, clutter, 2, points=60_000)
    n, h, m = floor_plane(sc.points_lidar, np.random.default_rng(0))
    up_true = sc.T_field_lidar[:3, :3].T @ [0, 0, 1]
    assert np.degrees(np.arccos(np.clip(n @ up_true, -1, 1))) < 0.3
    assert abs(h - sc.T_field_lidar[2, 3]) < 0.03
