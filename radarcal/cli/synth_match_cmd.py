"""``radarcal synth match``: a realistic match replay for ``radarcal run`` (visible-part boxes with jitter, misses,
false positives and label swaps; clouds fired point by point and delivered late; calibration error)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, command_line, emit, progress
from radarcal.errors import InputError

__all__ = ["synth_match", "parse_robot_windows"]


def parse_robot_windows(values: list[str] | None, option: str, need_times: bool) -> tuple:
    """``ROBOT:T0:T1`` (or ``ROBOT`` alone when ``need_times`` is False: the whole replay) -> ((label, t0, t1), ...)."""
    out = []
    for text in values or []:
        parts = text.split(":")
        label = parts[0]
        team, _, num = label.partition("_")
        if team not in ("red", "blue") or num not in tuple("1234567"):
            raise InputError(option, f"expected a robot label like blue_3, got {label!r} in {text!r}")
        if len(parts) == 1 and not need_times:
            out.append((label, 0.0, float("inf")))
            continue
        try:
            t0, t1 = (float(v) for v in parts[1:])
        except ValueError:
            raise InputError(option, f"expected ROBOT:T0:T1 (seconds), got {text!r}") from None
        if not 0 <= t0 < t1:
            raise InputError(option, f"expected 0 <= T0 < T1, got {text!r}")
        out.append((label, t0, t1))
    return tuple(out)


def synth_match(
    out: Path = typer.Argument(..., help="Output replay folder (created)."),
    field: str = typer.Option("rmuc2024", "--field", help="Built-in field name or a YAML/JSON field file."),
    frames: int = typer.Option(450, "--frames", help="Camera frames (30 fps)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (deterministic per seed)."),
    robots: int = typer.Option(9, "--robots", help="Ground robots (0..12) in the random scenario."),
    scenario: str = typer.Option("random", "--scenario", help="random | occlusion (crossing robots, one behind the central highland)."),
    no_aerial: bool = typer.Option(False, "--no-aerial", help="No aerial robot."),
    people: int = typer.Option(4, "--people", help="People walking along the boundary."),
    lidar_points: int = typer.Option(10_000, "--lidar-points", help="Points per 0.1 s sweep."),
    calib_rot: float = typer.Option(0.3, "--calib-rot-deg", help="Rotation error of the bundle's T_cam_lidar (deg)."),
    calib_trans: float = typer.Option(0.02, "--calib-trans-m", help="Translation error of the bundle's T_cam_lidar (m)."),
    pnp_px: float = typer.Option(1.5, "--pnp-px", help="Click noise (px) of the four-point field PnP."),
    camera_miss: list[str] = typer.Option(None, "--camera-miss", help="ROBOT:T0:T1 - the detector misses that robot in [T0, T1] s; the LiDAR still sees it (repeatable)."),
    lidar_miss: list[str] = typer.Option(None, "--lidar-miss", help="ROBOT:T0:T1 - the LiDAR gets no return from that robot in [T0, T1] s (dropout); the camera still sees it (repeatable)."),
    absent: list[str] = typer.Option(None, "--absent", help="ROBOT or ROBOT:T0:T1 - that robot is truly not on the field (whole replay or in [T0, T1] s; repeatable)."),
    as_json: JsonOpt = False,
) -> None:
    """Write a realistic match replay (clouds/, detections.jsonl, truth.jsonl, calib.yaml) — see docs/runtime.md."""
    from radarcal.field import load_field
    from radarcal.synth.detections import MatchConfig, write_match_replay

    if scenario not in ("random", "occlusion"):
        raise InputError("--scenario", f"expected random or occlusion, got {scenario!r}")
    if frames < 1 or not 0 <= robots <= 12 or people < 0 or lidar_points < 100:
        raise InputError("radarcal synth match", "--frames >= 1, --robots 0..12, --people >= 0, --lidar-points >= 100")
    from radarcal.io.outputs import check_output

    check_output(out, what="replay folder", folder=True)
    fm = load_field(field)
    cfg = MatchConfig(frames=frames, seed=seed, robots=robots, scenario=scenario, aerial=not no_aerial, people=people, lidar_points=lidar_points,
                      calib_rot_deg=calib_rot, calib_trans_m=calib_trans, pnp_px=pnp_px, camera_miss=parse_robot_windows(camera_miss, "--camera-miss", True),
                      absent=parse_robot_windows(absent, "--absent", False), lidar_miss=parse_robot_windows(lidar_miss, "--lidar-miss", True))  # fmt: skip
    prog = lambda it, description="": progress(it, description, enabled=not as_json)  # noqa: E731
    s = write_match_replay(out, fm, cfg, generator=command_line(), progress=prog)
    emit(s, as_json, lambda d: typer.echo(f"wrote {d['out']}: {d['frames']} frames, {d['clouds']} clouds, {d['robots']} robots, {d['boxes']} boxes "
                                          f"(+{d['false_positives']} false, {d['label_swaps']} swapped); field pose off {d['field_pose_rot_deg']:.2f} deg / {d['field_pose_cam_centre_m']:.3f} m"))  # fmt: skip
