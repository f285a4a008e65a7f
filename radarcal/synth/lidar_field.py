"""Generated clouds for ``radarcal lidar-field``: a Livox-Mid-70-like rosette integrated for seconds from a radar
station behind one end of a field *mesh*, ray-cast (open3d, exact triangles) against

- the field mesh itself (what the registration aligns to),
- ``clutter`` meshes that are real but not in the registration mesh (a team's filter mesh: bases, outposts, the
  central structure stand in it and not in the alignment mesh),
- robot-sized boxes standing on the field (dynamic: not in any mesh),
- the venue beyond the field (walls, stands, a ceiling — ``venue="hall"``; ``"open"``: distant walls only).

Pure functions; deterministic per seed. The truth ``T_field_lidar`` is returned with the cloud.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radarcal import geometry
from radarcal.field import FieldModel, box_mesh, merge_meshes
from radarcal.io.meshes import TriangleMesh
from radarcal.synth.lidar_patterns import livox_rosette_dirs

__all__ = ["LidarFieldSceneConfig", "LidarFieldScene", "station_pose", "box_mesh", "venue_mesh", "clutter_from", "lidar_field_scene", "LABELS"]

LABELS = ("field", "clutter", "robot", "venue")


@dataclass
class LidarFieldSceneConfig:
    seed: int = 0
    side: str = "red"                            # whose station: red (behind x = 0) or blue (behind x = L)
    duration_s: float = 5.0
    points: int = 300_000                        # fired rays over duration_s (60 k/s; sky returns are dropped)
    range_sigma: float = 0.02                    # m, along the ray
    robots: int = 10                             # robot-sized boxes on the field
    height_m: tuple[float, float] = (2.3, 2.8)   # LiDAR height above the ground
    pitch_deg: tuple[float, float] = (6.0, 12.0)  # pitched down by
    behind_m: tuple[float, float] = (0.4, 1.5)   # behind the end line
    venue: str = "hall"                          # hall | open


@dataclass
class LidarFieldScene:
    points_lidar: np.ndarray     # (N,3) float32, LiDAR frame
    labels: np.ndarray           # (N,) int: index into LABELS
    T_field_lidar: np.ndarray    # truth
    config: LidarFieldSceneConfig


def station_pose(field_model: FieldModel, rng: np.random.Generator, side: str = "red", height_m=(2.3, 2.8), pitch_deg=(6.0, 12.0), behind_m=(0.4, 1.5)) -> np.ndarray:
    """``T_field_lidar`` of a station behind the ``side`` end: x forward down the field (towards a point near the
    centre), pitched down, a little roll."""
    L, W = field_model.size
    pos = np.array([-rng.uniform(*behind_m), rng.uniform(0.15 * W, 0.85 * W), rng.uniform(*height_m)])
    target = np.array([L * 0.5 + rng.uniform(-3, 3), W * 0.5 + rng.uniform(-2, 2)])
    yaw = np.degrees(np.arctan2(target[1] - pos[1], target[0] - pos[0]))
    T = geometry.T_from_xyz_rpy_deg(*pos, rng.uniform(-1.0, 1.0), rng.uniform(*pitch_deg), yaw)
    if side == "blue":
        T = np.array([[-1.0, 0, 0, L], [0, -1.0, 0, W], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]) @ T
    elif side != "red":
        raise ValueError(f"side: expected red or blue, got {side!r}")
    return T


def venue_mesh(size: tuple[float, float], kind: str = "hall") -> TriangleMesh:
    """The hall around a field: ``hall`` — walls 6-8 m beyond the boundary up to 9 m, a ceiling at 9 m, stepped
    stands along both long sides; ``open`` — walls 25 m away only."""
    L, W = size
    if kind == "open":
        m = 25.0
        return merge_meshes([box_mesh(np.array([L / 2, -m, 0.0]), np.array([L + 2 * m, 0.5, 6.0]), 0.0),
                       box_mesh(np.array([L / 2, W + m, 0.0]), np.array([L + 2 * m, 0.5, 6.0]), 0.0),
                       box_mesh(np.array([-m, W / 2, 0.0]), np.array([0.5, W + 2 * m, 6.0]), 0.0),
                       box_mesh(np.array([L + m, W / 2, 0.0]), np.array([0.5, W + 2 * m, 6.0]), 0.0)])
    if kind != "hall":
        raise ValueError(f"venue: expected hall or open, got {kind!r}")
    parts = [box_mesh(np.array([L / 2, -8.0, 0.0]), np.array([L + 16, 0.3, 9.0]), 0.0),
             box_mesh(np.array([L / 2, W + 8.0, 0.0]), np.array([L + 16, 0.3, 9.0]), 0.0),
             box_mesh(np.array([-6.0, W / 2, 0.0]), np.array([0.3, W + 16, 9.0]), 0.0),
             box_mesh(np.array([L + 6.0, W / 2, 0.0]), np.array([0.3, W + 16, 9.0]), 0.0),
             box_mesh(np.array([L / 2, W / 2, 9.0]), np.array([L + 16, W + 16, 0.2]), 0.0)]
    for k in range(4):  # stands: four steps of 0.6 m rising away from the field on both long sides
        parts.append(box_mesh(np.array([L / 2, -2.5 - 1.2 * k, 0.0]), np.array([L, 1.2, 0.6 * (k + 1)]), 0.0))
        parts.append(box_mesh(np.array([L / 2, W + 2.5 + 1.2 * k, 0.0]), np.array([L, 1.2, 0.6 * (k + 1)]), 0.0))
    return merge_meshes(parts)


def clutter_from(mesh: TriangleMesh, field_model: FieldModel, min_distance_m: float = 0.1) -> TriangleMesh:
    """The triangles of ``mesh`` (e.g. a team's filter mesh) that are not in the field's mesh: centroid and all
    corners farther than ``min_distance_m`` from it (what stands on the field but is not registered to)."""
    import open3d as o3d

    scene = field_model.raycasting_scene()
    c = mesh.corners
    q = np.concatenate([c.mean(axis=1), c.reshape(-1, 3)]).astype(np.float32)
    d = scene.compute_distance(o3d.core.Tensor(q)).numpy()
    T = len(c)
    far = (d[:T] > min_distance_m) & np.all(d[T:].reshape(T, 3) > 0.5 * min_distance_m, axis=1)
    return TriangleMesh(mesh.vertices, mesh.triangles[far], mesh.source + " (not in the field mesh)", mesh.units)


def lidar_field_scene(field_model: FieldModel, config: LidarFieldSceneConfig, clutter: list[TriangleMesh] | None = None) -> LidarFieldScene:
    """Ray-cast one accumulated cloud (see the module docstring). The field model must be mesh-backed (or is
    triangulated from its polygons)."""
    import open3d as o3d

    ss = np.random.SeedSequence(config.seed)
    r_pose, r_rob, r_noise = (np.random.default_rng(s) for s in ss.spawn(3))
    T = station_pose(field_model, r_pose, config.side, config.height_m, config.pitch_deg, config.behind_m)
    L, W = field_model.size
    robots = []
    for _ in range(config.robots):
        xy = r_rob.uniform([1.0, 1.0], [L - 1.0, W - 1.0])
        z = float(field_model.surface_z(xy[None])[0])
        robots.append(box_mesh(np.array([xy[0], xy[1], z]), r_rob.uniform([0.45, 0.45, 0.4], [0.65, 0.6, 0.65]), r_rob.uniform(0, np.pi)))
    from radarcal.field import polygon_field_mesh

    groups = [[field_model.mesh if field_model.mesh is not None else polygon_field_mesh(field_model)], list(clutter or []), robots, [venue_mesh((L, W), config.venue)]]
    scene = o3d.t.geometry.RaycastingScene()
    gid_label = {}
    for label, meshes in enumerate(groups):
        for m in meshes:
            tm = o3d.t.geometry.TriangleMesh()
            tm.vertex.positions = o3d.core.Tensor(m.vertices.astype(np.float32))
            tm.triangle.indices = o3d.core.Tensor(m.triangles.astype(np.int32))
            gid_label[int(scene.add_triangles(tm))] = label
    t = np.arange(config.points) * (config.duration_s / config.points)
    d_l = livox_rosette_dirs(t)
    d_f = d_l @ T[:3, :3].T
    o_f = np.broadcast_to(T[:3, 3], d_f.shape)
    r = scene.cast_rays(o3d.core.Tensor(np.hstack([o_f, d_f]).astype(np.float32)))
    th = r["t_hit"].numpy().astype(float)
    gid = r["geometry_ids"].numpy().astype(np.int64)
    keep = np.isfinite(th) & (th > 0.3) & (th < 200)
    lut = np.full(max(gid_label) + 2, -1)
    for g, lab in gid_label.items():
        lut[g] = lab
    labels = lut[np.clip(gid[keep], 0, len(lut) - 1)]
    rng_m = th[keep] + r_noise.normal(0, config.range_sigma, int(keep.sum()))
    pts = (d_l[keep] * rng_m[:, None]).astype(np.float32)
    return LidarFieldScene(pts, labels, T, config)
