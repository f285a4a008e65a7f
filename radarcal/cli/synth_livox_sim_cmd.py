"""``radarcal synth livox-sim``: a simulated Livox LiDAR (SDK 1 or SDK 2) on a loopback address, for testing a station."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from radarcal.errors import InputError


def synth_livox_sim(
    model: str = typer.Option("mid70", "--model", help="mid70 | mid40 | avia (SDK 1), hap | mid360 (SDK 2)."),
    ip: str = typer.Option("127.0.0.2", "--ip", help="The simulated sensor's address (loopback 127.x.y.z only)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Host address the SDK 1 broadcasts go to (loopback only)."),
    discovery_port: int = typer.Option(None, "--discovery-port", help="SDK 1: host broadcast port (55000); SDK 2: the sensor's discovery port (56000)."),
    scene: Path = typer.Option(None, "--scene", help="Stream the clouds of a replay folder (`radarcal synth field`) instead of the built-in room."),
    rate: float = typer.Option(None, "--rate", help="Points per second (default: the model's, Mid-70 100 k, HAP 452 k)."),
    duration: float = typer.Option(None, "--duration", help="Stop after this many seconds (default: Ctrl-C)."),
    outage_at: float = typer.Option(None, "--outage-at", help="Go silent (no heartbeat answers, no data) at this time (s)."),
    outage_s: float = typer.Option(2.0, "--outage-s", help="Length of the outage (s)."),
    packets: int = typer.Option(None, "--packets", help="Stop after streaming this many point packets."),
    bad_every: float = typer.Option(0.0, "--bad-every", help="Send one malformed and one truncated packet every this many seconds (0: never)."),
) -> None:
    """Answer discovery and handshake, stream a generated scene at the sensor's packet rate, drop heartbeats on request."""
    from radarcal.synth.livox_sim import MODELS, LivoxSimulator

    if model not in MODELS:
        raise InputError("--model", f"expected one of {', '.join(MODELS)}")
    for a in (ip, host):
        if not a.startswith("127."):
            raise InputError("--ip/--host", f"{a}: the simulator runs on loopback addresses (127.x.y.z) only")
    if scene is not None and not (scene / "clouds").is_dir():
        raise InputError(scene, "no clouds/ folder (expected a `radarcal synth field` replay folder)")
    sim = LivoxSimulator(model, ip=ip, host=host, discovery_port=discovery_port, rate=rate, scene=scene, max_packets=packets).start()
    url = f"livox{sim.sdk}://{ip}?host={host}" + (f"&discovery_port={discovery_port}" if discovery_port else "")
    typer.echo(f"simulated {model} (SDK {sim.sdk}) on {ip}: radarcal run --clouds '{url}' ...", err=True)
    t0 = time.monotonic()
    did_outage = False
    last_bad = t0
    try:
        while duration is None or time.monotonic() - t0 < duration:
            time.sleep(0.05)
            if sim.done():
                time.sleep(0.5)
                break
            now = time.monotonic() - t0
            if outage_at is not None and not did_outage and now >= outage_at:
                sim.outage(outage_s)
                did_outage = True
            if bad_every and time.monotonic() - last_bad >= bad_every:
                last_bad = time.monotonic()
                sim.inject("malformed")
                sim.inject("truncated")
    except KeyboardInterrupt:
        pass
    finally:
        sim.close()
    typer.echo(f"sent {sim.packets_sent} packets ({sim.slots_sent} point slots), {sim.points_sent} points, {sim.bad_sent} malformed, {sim.truncated_sent} truncated; handshakes {sim.handshakes}")
