"""``radarcal synth radar``: a radar-reflector calibration session with known truth (for ``radarcal radar-lidar``)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit
from radarcal.io.outputs import check_output
from radarcal.errors import InputError


def synth_radar(
    out: Path = typer.Argument(..., help="Session folder to write (rig.yaml, scenes/<k>/, truth.json)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed -> same files)."),
    scenes: int = typer.Option(4, "--scenes", help="Reflector placements."),
    reflectors: int = typer.Option(3, "--reflectors", help="Reflectors per placement."),
    sigma: float = typer.Option(0.02, "--sigma", help="Radar noise per axis (m)."),
    quantise: float = typer.Option(0.0, "--quantise", help="Radar coordinate grid (m); ARS408 object lists use 0.2."),
    frames: int = typer.Option(1, "--frames", help="Radar frames per placement (averaged by radar-lidar)."),
    p_miss: float = typer.Option(0.05, "--p-miss", help="Probability of a missed detection."),
    ghosts: float = typer.Option(0.3, "--ghosts", help="Mean ghost detections per radar and frame."),
    lidar_noise: float = typer.Option(0.005, "--lidar-noise", help="LiDAR range noise (m)."),
    extra_lidars: int = typer.Option(0, "--extra-lidars", help="Extra LiDARs (0-2: left, right) for LiDAR-LiDAR registration."),
    bad_reflector: float = typer.Option(0.0, "--bad-reflector", help="Displace every radar return of one reflector by this (m)."),
    heights: str = typer.Option("0.55,0.50,0.60", "--radar-heights", help="Mounting heights of the left,middle,right radars (m)."),
    family: str = typer.Option("", "--family", help="A preset with every held-out feature: tune or check (other layout, heights, noise); the options above are then ignored."),
    tripod: str = typer.Option("pole", "--tripod", help="pole (a mast under the head) or legs (three splayed legs below a gap)."),
    turn: float = typer.Option(0.0, "--turn-deg", help="Reflectors turned away from the LiDAR by up to this (deg)."),
    layout: str = typer.Option("clutter", "--layout", help="clutter (boxes and walls beyond the gate) or ground_wall (ground and one wall)."),
    low_rcs: int = typer.Option(0, "--low-rcs-clutter", help="Static low-RCS radar returns per placement (tripod feet, region)."),
    multipath: float = typer.Option(0.0, "--multipath", help="Probability of a ground-bounce ghost per reflector and radar."),
    radar_format: str = typer.Option("csv", "--radar-format", help="csv (radar.csv) or ars408 (one object list per radar)."),
    as_json: JsonOpt = False,
) -> None:
    """Vehicle with a front LiDAR, left/middle/right 2D radars and corner reflectors on tripods."""
    from radarcal.synth.radar import (
        RadarRigSpec,
        RadarSceneSpec,
        _default_extra_lidars,
        _default_radars,
        feature_spec,
        generate_radar_session,
        write_radar_session,
    )

    try:
        hs = [float(v) for v in heights.split(",")]
    except ValueError:
        raise InputError("--radar-heights", f"expected three numbers, got {heights!r}") from None
    if len(hs) != 3 or min(hs) <= 0:
        raise InputError("--radar-heights", f"expected three positive heights, got {heights!r}")
    if not 0 <= extra_lidars <= 2:
        raise InputError("--extra-lidars", "expected 0, 1 or 2")
    if scenes < 1 or reflectors < 2 or frames < 1:
        raise InputError("--scenes/--reflectors/--frames", "need >= 1 scene, >= 2 reflectors, >= 1 frame")
    check_output(out, what="session folder", folder=True)
    for opt, val, ok in (("--tripod", tripod, ("pole", "legs")), ("--layout", layout, ("clutter", "ground_wall")), ("--radar-format", radar_format, ("csv", "ars408")),
                         ("--family", family, ("", "tune", "check"))):
        if val not in ok:
            raise InputError(opt, f"expected one of {', '.join(o for o in ok if o)}, got {val!r}")
    radars = _default_radars()
    radars = {n: (x, y, h, yaw) for (n, (x, y, _, yaw)), h in zip(radars.items(), hs)}
    extra = dict(list(_default_extra_lidars().items())[:extra_lidars])
    spec = RadarSceneSpec(rig=RadarRigSpec(radars=radars, extra_lidars=extra), n_scenes=scenes, reflectors_per_scene=reflectors, radar_sigma=sigma,
                          quantisation=quantise, n_frames=frames, p_miss=p_miss, ghost_rate=ghosts, lidar_noise=lidar_noise, bad_reflector_offset=bad_reflector,
                          tripod=tripod, reflector_turn_deg=(0.0, turn), layout=layout, low_rcs_clutter=low_rcs, multipath=multipath, seed=seed)
    if family:
        spec = feature_spec(seed, family)
        scenes, reflectors = spec.n_scenes, spec.reflectors_per_scene
    ses = generate_radar_session(spec)
    write_radar_session(ses, out, radar_format)
    n_det = sum(len(s["radar"]["xy"]) for s in ses.scenes)
    summary = {"out": str(out), "seed": seed, "scenes": scenes, "reflectors_per_scene": reflectors, "lidars": list(ses.rig["lidars"]), "radars": list(ses.rig["radars"]), "radar_detections": n_det}
    emit(summary, as_json, lambda s: typer.echo(f"wrote {out}: {scenes} placement(s) x {reflectors} reflectors, LiDARs {', '.join(s['lidars'])}, radars {', '.join(s['radars'])}, {n_det} radar detections (truth.json)"))
