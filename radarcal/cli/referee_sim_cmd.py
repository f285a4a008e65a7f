"""``radarcal referee-sim``: play the referee system against ``radarcal run --serial`` and score its marks (docs/runtime.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit
from radarcal.errors import InputError

__all__ = ["referee_sim", "format_table"]


def format_table(s: dict) -> list[str]:
    """The score table of a simulated match as text lines."""
    lines = [f"referee-sim season {s['season']} ({s['team']} radar): {s['match_s']:.1f} s of match, stopped: {s.get('stopped_by', '-')}",
             f"{'robot':8s} {'correct s':>9s} {'wrong s':>8s} {'unsent s':>8s} {'off s':>6s} {'vulnerable':>10s} {'max prog':>8s} {'score':>8s}"]  # fmt: skip
    for r in s["robots"]:
        vul = "-" if r["vulnerable_frac"] is None else f"{100 * r['vulnerable_frac']:.1f} %"
        prog = "-" if r["max_progress"] is None else f"{r['max_progress']:.0f}"
        lines.append(f"{r['robot']:8s} {r['correct_s']:9.1f} {r['wrong_s']:8.1f} {r['unsent_s']:8.1f} {r['off_field_s']:6.1f} {vul:>10s} {prog:>8s} {r['score']:8.1f}")
    t = s["total"]
    lines.append(f"{'total':8s} {t['correct_s']:9.1f} {t['wrong_s']:8.1f} {'':8s} {'':6s} {'':10s} {'':8s} {t['score']:8.1f}")
    k = s["link"]
    cmds = ", ".join(f"{c} {n}" for c, n in k["by_cmd"].items()) or "none"
    lines.append(f"link: {k['frames']} frames from radarcal ({cmds}); layout checked {k['layout_checked']}; malformed {k.get('malformed_total', k['malformed'])} "
                 f"(CRC8 {k.get('bad_crc8', 0)}, CRC16 {k.get('bad_crc16', 0)}, length {k.get('bad_length', 0)}, content {k['malformed']}); "
                 f"over rate {k['over_rate']}, over link budget {k['over_link_budget']}, over 0x0301 budget {k['over_interaction_budget']}")  # fmt: skip
    if k["problems"]:
        lines.append("  problems: " + ", ".join(f"{p} x{n}" for p, n in k["problems"].items()))
    d = s["double_vulnerability"]
    lines.append(f"double vulnerability: {d['granted']} chances granted, {d['used']} used, {d['refused']} refused, {d['illegal']} illegal requests")
    return lines


def referee_sim(
    replay: Path = typer.Option(..., "--replay", help="Replay folder with truth.jsonl (the one `radarcal run --replay` plays)."),
    season: int = typer.Option(..., "--season", help="Referee season 2021..2026 (layouts, rates, mark rule: docs/runtime.md)."),
    pty: bool = typer.Option(True, "--pty/--no-pty", help="Open a pseudo-terminal and print its path (pass it to `radarcal run --serial PATH`)."),
    port: str = typer.Option(None, "--port", help="A real serial device instead of a pty (115200 8N1)."),
    team: str = typer.Option(None, "--team", help="The radar's colour red|blue (default: the replay's station, else red)."),
    record: Path = typer.Option(None, "--record", help="Write every frame both ways (JSON lines with times, hex and the decoded check) here."),
    match_s: float = typer.Option(420.0, "--match-s", help="Match length for the game-status clock (s)."),
    mark_hold: float = typer.Option(1.0, "--mark-hold", help="A received mark stands for this long (s; simulator assumption)."),
    mark_radius: float = typer.Option(None, "--mark-radius", help="Correct-mark radius (m; default: the season's, 0.6)."),
    dv_grant: list[float] = typer.Option(None, "--dv-grant", help="Match time (s) at which the radar gains a double-vulnerability chance (repeatable; default: 1/3 and 2/3 of the replay)."),
    score_correct: float = typer.Option(None, "--score-correct", help="Points per second correctly marked (default: the season's, +5, UNCERTAIN)."),
    score_wrong: float = typer.Option(None, "--score-wrong", help="Points per second wrong or not sent (default: the season's, -10, UNCERTAIN)."),
    idle_exit: float = typer.Option(3.0, "--idle-exit", help="Stop when radarcal has sent nothing for this long (s)."),
    start_timeout: float = typer.Option(120.0, "--start-timeout", help="Give up when radarcal sends nothing within this long (s)."),
    speed: float = typer.Option(1.0, "--speed", help="Match clock at this multiple of wall time (give `radarcal run` the same --speed)."),
    as_json: JsonOpt = False,
) -> None:
    """Play the referee over a pseudo-terminal: status, HP, mark feedback, DV chances; score radarcal's marks against the truth.

    The first line on stdout is the pty's path; the score table (or --json summary) follows when the match ends."""
    import sys

    from radarcal.runtime.referee_season import KNOWN_SEASONS, rules
    from radarcal.synth.referee_serve import PtyPort, SerialPort, open_pty, replay_truth, serve_until_signal
    from radarcal.synth.referee_sim import RefereeSim

    if season not in KNOWN_SEASONS:
        raise InputError("--season", f"referee season {season} is not one radarcal knows ({KNOWN_SEASONS[0]}..{KNOWN_SEASONS[-1]})")
    if team is not None and team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {team!r}")
    for name, v in (("--match-s", match_s), ("--mark-hold", mark_hold), ("--idle-exit", idle_exit), ("--start-timeout", start_timeout), ("--speed", speed)):
        if not v > 0:
            raise InputError(name, f"must be > 0, got {v}")
    if mark_radius is not None and not mark_radius > 0:
        raise InputError("--mark-radius", f"must be > 0, got {mark_radius}")
    rep, truth = replay_truth(replay)
    if record is not None:
        from radarcal.cli.outputs import check_output

        mine = {Path(q).resolve(): f"the replay's {Path(q).name}" for q in (rep.truth, rep.bundle, rep.detections, rep.root / "meta.json") if q is not None}
        check_output(record, mine, what="frame log")
    team = team or str(rep.meta.get("station", "red"))
    r = rules(season)
    over = {k: v for k, v in (("score_correct_per_s", score_correct), ("score_wrong_per_s", score_wrong), ("mark_radius_m", mark_radius)) if v is not None}
    if over:
        r = r.replace(**over)
    grants = tuple(dv_grant) if dv_grant else ((truth.duration / 3, 2 * truth.duration / 3) if r.dv_max_chances.value else ())
    sim = RefereeSim(r, truth, team=team, match_s=match_s, mark_hold_s=mark_hold, dv_grants=grants)

    if port is not None:
        try:
            link = SerialPort(port)
        except Exception as e:  # noqa: BLE001 - SerialException, OSError ...
            raise InputError("--port", f"cannot open {port}: {e}") from None
    elif pty:
        link = PtyPort(*open_pty())
    else:
        raise InputError("radarcal referee-sim", "give --pty (default) or --port DEV")
    typer.echo(link.path)  # the first line: what `radarcal run --serial` opens
    sys.stdout.flush()
    res = serve_until_signal(sim, link, record, idle_exit_s=idle_exit, start_timeout_s=start_timeout, speed=speed)
    summary = res.summary
    summary.update({"port": link.path, "replay": str(replay), "record": str(record) if record else None, "dv_grants": list(grants)})
    emit(summary, as_json, lambda s: [typer.echo(line) for line in format_table(s)])
    if not res.started:
        typer.echo(f"error: radarcal sent nothing ({res.stopped_by})", err=True)
        raise typer.Exit(1)
