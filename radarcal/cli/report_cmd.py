"""``radarcal report BUNDLE [--session DIR] [--tracks FILE [--truth FILE]] -o report.html``: one self-contained HTML
page with every figure the bundle's session files allow (see docs/report.md). Parse, call
:func:`radarcal.report.make.make_report`, print."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit, err_console
from radarcal.cli.outputs import check_outputs


def report(
    bundle: Path = typer.Argument(..., help="Calibration bundle (YAML)."),
    output: Path = typer.Option(..., "--output", "-o", help="HTML file to write (one self-contained page)."),
    session: Path = typer.Option(None, "--session", help="Folder of session .npz files (default: next to the bundle, as referenced by it)."),
    tracks: Path = typer.Option(None, "--tracks", help="Track file written by `radarcal run --out` (JSON lines): adds a minimap."),
    truth: Path = typer.Option(None, "--truth", help="Ground-truth tracks in the same format (needs --tracks): adds the error over time."),
    title: str = typer.Option("", "--title", help="Report title (default: the bundle file name)."),
    dpi: int = typer.Option(96, "--dpi", min=30, max=300, help="Figure resolution."),
    as_json: JsonOpt = False,
) -> None:
    """Build an HTML report (figures inline) from a bundle and its session files."""
    from radarcal.bundle import load_bundle
    from radarcal.report.make import check_report_inputs, make_report

    b = load_bundle(bundle)
    check_report_inputs(session, tracks, truth)
    check_outputs(bundle, [("report", output)], b, inputs=[tracks, truth])
    err_console.print(f"[dim]building report from {bundle} ({len(b.sessions)} session file(s))…[/dim]")
    res = make_report(b, output, session, tracks, truth, title, dpi)

    def human(s: dict) -> None:
        typer.echo(f"wrote {s['output']} ({s['bytes'] / 1e6:.2f} MB): {s['figures']} figure(s) in {len(s['sections'])} section(s)")
        for t in s["sections"]:
            typer.echo(f"  - {t}")
        for k in s["skipped"]:
            typer.echo(f"  skipped: {k}")
        for w in s["warnings"]:
            typer.echo(f"  warning: {w}")

    emit(res.to_dict(), as_json, human)
