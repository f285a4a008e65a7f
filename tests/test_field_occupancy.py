"""FieldModel.occupancy_grid: the static-structure test (numpy gather) against exact geometry, both backings."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.field import load_field
from tests.conftest import shared_dataset


@pytest.fixture(scope="module")
def poly():
    return load_field("rmuc2024")


@pytest.fixture(scope="module")
def mesh_field():
    return load_field(shared_dataset("hitsz_rmuc_field_meshes") / "24_bg2align_fix1.stl")


def _exact_distance_polygons(fm, p):
    """Distance of points to the polygon field's solid: exact to its triangulation (open3d) and to a 2 cm sampling
    of the structure boxes."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    from radarcal.field import _box_surface_samples, _o3d_scene, polygon_field_mesh

    d = _o3d_scene(polygon_field_mesh(fm)).compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy()
    return np.minimum(d, cKDTree(_box_surface_samples(fm.structures, 0.02)).query(p)[0])


@pytest.mark.slow
def test_polygon_grid_matches_distance(poly):
    grid = poly.occupancy_grid(voxel=0.08, grow=0.3)
    rng = np.random.default_rng(0)
    p = rng.uniform([-0.5, -0.5, -0.2], [28.5, 15.5, 2.0], (40000, 3))
    d = _exact_distance_polygons(poly, p)
    d[p[:, 2] <= poly.surface_z(p[:, :2])] = 0.0  # inside the solid (under a raised area's top)
    c = grid.contains(p)
    # every point within grow - one voxel diagonal is inside, every point beyond grow + one diagonal is outside
    diag = 0.08 * np.sqrt(3)
    assert np.all(c[d < 0.3 - diag])
    assert not np.any(c[d > 0.3 + diag])


def test_polygon_grid_known_points(poly):
    grid = poly.occupancy_grid(voxel=0.08, grow=0.3)
    # known points: ground, 0.5 m above ground, over the central highland top, inside a structure, far away
    q = np.array([[5, 5, 0.1], [5, 5, 0.5], [14, 7.5, 0.85], [14, 7.5, 1.0], [1.5, 7.5, 1.0], [40, 40, 0]])
    np.testing.assert_array_equal(grid.contains(q), [True, False, True, False, True, False])


def test_mesh_grid_matches_open3d_distance(mesh_field):
    import open3d as o3d

    grid = mesh_field.occupancy_grid(voxel=0.08, grow=0.3)
    scene = mesh_field.raycasting_scene()
    rng = np.random.default_rng(1)
    p = rng.uniform([0, 0, -0.1], [28, 15, 2.5], (60000, 3))
    d = scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy()
    d[p[:, 2] <= mesh_field.surface_z(p[:, :2])] = 0.0  # under the top surface: inside the solid
    c = grid.contains(p)
    diag = 0.08 * np.sqrt(3)
    assert np.mean(c[d < 0.3 - diag]) > 0.999
    # the solid under the top surface is filled before growing, so a few points above thin tall parts count too
    assert np.mean(c[d > 0.3 + diag]) < 1e-3
    assert grid.contains(np.zeros((0, 3))).shape == (0,)


def test_grid_is_cached_and_float32_ok(poly):
    g1 = poly.occupancy_grid()
    assert poly.occupancy_grid() is g1
    p = np.array([[5, 5, 0.1]], np.float32)
    assert g1.contains(p)[0]
