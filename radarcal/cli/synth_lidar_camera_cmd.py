"""``radarcal synth lidar-camera``: write a ground-truth LiDAR-camera scene (image, cloud, truth, init, bundle)."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from radarcal import geometry
from radarcal.cli.common import JsonOpt, command_line, emit, err_console
from radarcal.io.outputs import check_output
from radarcal.errors import InputError

__all__ = ["synth_lidar_camera"]


def synth_lidar_camera(
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (created)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (the scene is deterministic for a seed)."),
    lidar: str = typer.Option("rosette", "--lidar", help="rosette (Livox Mid-70-like) or spinning (multi-beam)."),
    duration: float = typer.Option(2.0, "--duration", help="Accumulation time in seconds."),
    rate: float = typer.Option(100_000.0, "--rate", help="LiDAR points per second."),
    beams: int = typer.Option(64, "--beams", help="Beams of the spinning LiDAR."),
    range_noise: float = typer.Option(0.02, "--range-noise", help="LiDAR range noise sigma (m)."),
    boards: int = typer.Option(0, "--boards", help="Number of chessboard calibration boards placed in the scene."),
    init_deg: float = typer.Option(3.0, "--init-deg", help="Rotation error of the initial guess written to init.json (deg)."),
    init_m: float = typer.Option(0.10, "--init-m", help="Translation error of the initial guess (m)."),
    supersample: int = typer.Option(2, "--supersample", help="Rays per pixel side for anti-aliasing."),
    family: str = typer.Option("structured", "--family", help="structured (the scene above) or family2 (an independent family: corridors, a RoboMaster-like field, parking lots; Avia/Horizon-like or 32/64-beam scans; cameras drawn per seed; --lidar avia|horizon|spin32|spin64, --layout)."),
    layout: str = typer.Option("", "--layout", help="family2 only: corridor, field or parking (default: from the seed)."),
    as_json: JsonOpt = False,
) -> None:
    """Generate a structured scene seen by a Livox-like LiDAR and a distorted 1280x1024 camera, with known T_cam_lidar."""
    from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene, write_lidar_camera_scene

    from radarcal.synth.lidar_camera_family2 import LAYOUTS, LIDARS, Family2Params, render_family2_scene

    if family not in ("structured", "family2"):
        raise InputError("--family", f"expected 'structured' or 'family2', got {family!r}")
    if family == "structured" and lidar not in ("rosette", "spinning"):
        raise InputError("--lidar", f"expected 'rosette' or 'spinning', got {lidar!r}")
    if family == "family2" and lidar != "rosette" and lidar not in LIDARS:  # rosette (the option's default): from the seed
        raise InputError("--lidar", f"family2: expected one of {', '.join(LIDARS)}, got {lidar!r}")
    if layout and (family != "family2" or layout not in LAYOUTS):
        raise InputError("--layout", f"family2 only, one of {', '.join(LAYOUTS)}; got {layout!r}")
    if duration <= 0 or rate <= 0:
        raise InputError("--duration/--rate", "must be positive")
    check_output(out, what="scene folder", folder=True)
    t0 = time.perf_counter()
    with err_console.status("ray-casting the scene"):
        if family == "family2":
            scene = render_family2_scene(Family2Params(seed=seed, layout=layout or None, lidar=None if lidar == "rosette" else lidar, duration_s=duration,
                                                       init_deg=init_deg, init_m=init_m))
        else:
            scene = render_lidar_camera_scene(LidarCameraSceneParams(seed=seed, lidar=lidar, duration_s=duration, point_rate=rate, beams=beams, range_noise_m=range_noise,
                                                                     boards=boards, init_deg=init_deg, init_m=init_m, supersample=supersample))
        paths = write_lidar_camera_scene(scene, out, command=command_line())
    xyz_rpy = geometry.T_to_xyz_rpy_deg(scene.T_cam_lidar)
    summary = {"out": str(out), "files": {k: str(v) for k, v in paths.items()}, "n_points": int(len(scene.points)), "T_cam_lidar": scene.T_cam_lidar,
               "init_error_deg_m": list(geometry.pose_error(scene.T_init, scene.T_cam_lidar)), "boards_visible": int(sum(b["visible"] for b in scene.boards)),
               "seconds": time.perf_counter() - t0}

    def human(s: dict) -> None:
        typer.echo(f"wrote {out}: image.png {scene.camera.width}x{scene.camera.height}, cloud.pcd {s['n_points']} points ({scene.params.get('lidar', lidar)}), truth.json, init.json, bundle.yaml")
        typer.echo(f"  true T_cam_lidar: xyz=({xyz_rpy[0]:.4f}, {xyz_rpy[1]:.4f}, {xyz_rpy[2]:.4f}) m rpy=({xyz_rpy[3]:.3f}, {xyz_rpy[4]:.3f}, {xyz_rpy[5]:.3f}) deg")
        typer.echo(f"  init.json off by {s['init_error_deg_m'][0]:.2f} deg / {s['init_error_deg_m'][1]:.3f} m; boards visible: {s['boards_visible']}; {s['seconds']:.1f} s")

    emit(summary, as_json, human)
