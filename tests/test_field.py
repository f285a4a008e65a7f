"""Field model: built-in RMUC field, surface heights, ray intersection, YAML/JSON loading and its errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from radarcal.errors import InputError
from radarcal.field import BUILTIN_FIELDS, REQUIRED_LANDMARKS, FieldModel, load_field


@pytest.fixture(scope="module")
def fm() -> FieldModel:
    return load_field("rmuc2024")


def test_builtin_has_documented_landmarks(fm):
    assert "rmuc2024" in BUILTIN_FIELDS
    assert fm.size == (28.0, 15.0)
    assert len(fm.landmarks) >= 8
    for name in REQUIRED_LANDMARKS:
        assert name in fm.landmarks
    P = np.stack(list(fm.landmarks.values()))
    assert np.all(P[:, 0] >= 0) and np.all(P[:, 0] <= 28) and np.all(P[:, 1] >= 0) and np.all(P[:, 1] <= 15) and np.all(P[:, 2] >= 0)
    # the field is centrally symmetric: every red landmark has a blue twin at (28 - x, 15 - y, z)
    for name, p in fm.landmarks.items():
        if name.startswith("red_"):
            twin = "_".join({"red": "blue", "south": "north", "north": "south"}.get(w, w) for w in name.split("_"))
            np.testing.assert_allclose(fm.landmarks[twin], [28 - p[0], 15 - p[1], p[2]])
    # the bases sit on the long axis' centre line, the red one near x = 0 (red half is x < 14)
    assert fm.landmarks["red_base"][0] < 3 and fm.landmarks["blue_base"][0] > 25
    assert fm.landmarks["red_base"][1] == 7.5


def test_surface_heights(fm):
    xy = np.array([[14.0, 7.5], [11.2, 7.5], [16.8, 7.5], [3.0, 3.0], [7.0, 2.0], [21.0, 13.0], [30.0, 7.0]])
    np.testing.assert_allclose(fm.surface_z(xy), [0.6, 0.3, 0.3, 0.0, 0.4, 0.4, 0.0], atol=1e-12)
    np.testing.assert_array_equal(fm.area_at(xy[:1]), [[a["name"] for a in fm.areas].index("central_highland")])


def test_intersect_known_rays(fm):
    o = np.array([[14.0, 7.5, 5.0], [5.0, 7.5, 0.3], [5.0, 5.5, 0.3], [5.0, 5.5, 1.0], [3.0, 3.0, 1.0]])
    d = np.array([[0, 0, -2.0], [1, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, -0.5]])
    hits = fm.intersect_rays(o, d)
    np.testing.assert_allclose(hits[0], [14, 7.5, 0.6], atol=1e-12)   # top of the central highland
    np.testing.assert_allclose(hits[1], [11.2, 7.5, 0.3], atol=1e-12)  # half-way up the red ramp
    np.testing.assert_allclose(hits[2], [12.5, 5.5, 0.3], atol=1e-12)  # chamfered wall (12,6)-(13,5) of the highland
    assert np.all(np.isnan(hits[3]))                                     # looking up: no hit
    np.testing.assert_allclose(hits[4], [5.0, 3.0, 0.0], atol=1e-12)   # ground


def test_ray_hits_are_first_hits(fm):
    """Random rays from a radar-station height: the hit lies on the surface solid and nothing before it does."""
    rng = np.random.default_rng(3)
    n = 4000
    o = np.column_stack([rng.uniform(-1, 29, n), rng.uniform(-1, 16, n), rng.uniform(0.05, 3, n)])
    d = np.column_stack([rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(-1, -0.02, n)])
    o = o[fm.surface_z(o[:, :2]) < o[:, 2]]
    d = d[: len(o)]
    t, _ = fm.ray_hits(o, d)
    assert np.all(np.isfinite(t))  # every downward ray hits at least the ground
    p = o + t[:, None] * d
    step = 1e-6 * d[:, :2] / np.linalg.norm(d[:, :2], axis=1, keepdims=True)
    sz = fm.surface_z(p[:, :2] + step)  # wall hits sit on an area's boundary: look just past it
    assert np.all(p[:, 2] <= sz + 1e-6) and np.all(p[:, 2] >= -1e-9)
    for f in np.linspace(0.0, 0.999, 40):  # points before the hit are above the surface
        q = o + (t * f)[:, None] * d
        assert np.all(q[:, 2] >= fm.surface_z(q[:, :2]) - 1e-9)


def test_raster_march_is_the_first_sample_below_a_dense_walk():
    """The height-raster march against a 2 mm walk along each ray on a raster of random blocks, steps and a ramp
    (no mesh needed): rays from above the surface in every direction, up, down, from off the raster and leaving it."""
    from radarcal.field import HeightRaster

    rng = np.random.default_rng(11)
    res, nx, ny = 0.02, 500, 300  # 10 x 6 m from (-1, 2)
    z = np.zeros((ny, nx), np.float32)
    for _ in range(40):
        x0, y0 = rng.integers(0, nx - 10), rng.integers(0, ny - 10)
        z[y0 : y0 + rng.integers(1, 60), x0 : x0 + rng.integers(1, 60)] = rng.uniform(0.02, 1.6)
    z[:, 400:450] = np.linspace(0.0, 0.5, 50)[None]  # a ramp
    hr = HeightRaster(-1.0, 2.0, res, z)
    n = 300
    xy = rng.uniform([-4, -1], [12, 11], (n, 2))
    o = np.column_stack([xy, hr.lookup(xy) + rng.uniform(0.05, 3.0, n)])
    d = rng.normal(size=(n, 3))
    d[: n // 2, 2] = -np.abs(d[: n // 2, 2])  # half of them downward: most hit
    t = hr.march(o, d)
    # reference: the first 2 mm sample below the surface (the raster is 0 off its box: the ground continues)
    dn = np.linalg.norm(d, axis=1)
    ts = np.arange(1, 12_000)[None] * (0.002 / dn)[:, None]  # 24 m along each ray
    q = o[:, None] + ts[..., None] * d[:, None]
    below = q[..., 2] <= hr.lookup(q[..., :2].reshape(-1, 2)).reshape(ts.shape)
    ref = np.where(below.any(axis=1), ts[np.arange(n), np.argmax(below, axis=1)], np.nan)
    with np.errstate(invalid="ignore"):
        near = ~((ref * dn > 23.9) | (t * dn > 23.9))  # hits beyond the walk's end are not compared
    assert np.mean(np.isnan(t[near]) == np.isnan(ref[near])) >= 0.99
    both = near & np.isfinite(t) & np.isfinite(ref)
    err = np.abs(t[both] - ref[both]) * dn[both]
    assert both.sum() > 100 and np.mean(err < 0.01) >= 0.98, np.percentile(err, [50, 95, 99])


def test_roundtrip_yaml_and_json(fm, tmp_path):
    y = tmp_path / "f.yaml"
    y.write_text(yaml.safe_dump(fm.to_dict()))
    j = tmp_path / "f.json"
    j.write_text(json.dumps(fm.to_dict()))
    for p in (y, j):
        g = load_field(str(p))
        assert g.name == fm.name and set(g.landmarks) == set(fm.landmarks)
        xy = np.random.default_rng(0).uniform([0, 0], [28, 15], (500, 2))
        np.testing.assert_array_equal(g.surface_z(xy), fm.surface_z(xy))
        assert len(g.structures) == len(fm.structures)


def test_minimal_user_file(tmp_path):
    p = tmp_path / "mine.yaml"
    p.write_text("name: lab\nsize: [10, 6]\nlandmarks:\n  a: [0, 0, 0]\n  b: [10, 0, 0]\n  c: [10, 6, 0.5]\n  d: [0, 6, 0]\n")
    f = load_field(str(p))
    assert f.size == (10.0, 6.0) and f.outline.shape == (4, 2) and f.areas == []
    np.testing.assert_array_equal(f.surface_z(np.array([[5.0, 3.0]])), [0.0])


@pytest.mark.parametrize(
    "text, words",
    [
        ("name: x\nsize: [10, 6]\n", "landmarks"),
        ("name: x\nsize: [10]\nlandmarks: {a: [0, 0, 0]}\n", "size"),
        ("name: x\nsize: [10, 6]\nlandmarks: {a: [0, 0]}\n", "landmarks.a"),
        ("name: x\nsize: [10, 6]\nlandmarks: {a: [0, 0, 0]}\nareas: [{name: h, polygon: [[0, 0], [1, 0], [1, 1]]}]\n", "areas[0].z"),
        ("name: x\nsize: [10, 6]\nlandmarks: {a: [0, 0, 0]}\nareas: [{name: h, polygon: [[0, 0], [1, 0]], z: 1}]\n", "areas[0].polygon"),
        ("name: x\nsize: [10, 6]\nlandmarks: {a: [0, 0, 0]}\nareas: [{name: h, polygon: [[0, 0], [1, 0], [2, 0]], z: 1}]\n", "zero area"),
        ("- just a list\n", "top level"),
        ("name: x\nsize: [10, 6\n", "cannot parse"),
    ],
)
def test_bad_files_one_line_errors(tmp_path, text, words):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        load_field(str(p))
    msg = str(e.value)
    assert str(p) in msg and words in msg and "\n" not in msg


def test_unknown_name(tmp_path):
    with pytest.raises(InputError, match="built-in: rmuc2024"):
        load_field("rmuc1999")
