"""``radarcal report BUNDLE [--session DIR] [--tracks FILE [--truth FILE]] -o report.html``: one self-contained HTML
page with every figure the bundle's session files allow (see docs/report.md)."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit, err_console
from radarcal.errors import InputError


def report(
    bundle: Path = typer.Argument(..., help="Calibration bundle (YAML)."),
    output: Path = typer.Option(..., "--output", "-o", help="HTML file to write (one self-contained page)."),
    session: Path = typer.Option(None, "--session", help="Folder of session .npz files (default: next to the bundle, as referenced by it)."),
    tracks: Path = typer.Option(None, "--tracks", help="Track file written by `radarcal run --out` (JSON lines): adds a minimap."),
    truth: Path = typer.Option(None, "--truth", help="Ground-truth tracks in the same format: adds the error over time."),
    title: str = typer.Option("", "--title", help="Report title (default: the bundle file name)."),
    dpi: int = typer.Option(96, "--dpi", min=30, max=300, help="Figure resolution."),
    as_json: JsonOpt = False,
) -> None:
    """Build an HTML report (figures inline) from a bundle and its session files."""
    from radarcal.bundle import load_bundle
    from radarcal.report.build import build_report
    from radarcal.report.html import render_html

    b = load_bundle(bundle)
    if tracks is not None and not tracks.is_file():
        raise InputError(tracks, "track file not found")
    if truth is not None and not truth.is_file():
        raise InputError(truth, "truth track file not found")
    if output.exists() and output.is_dir():
        raise InputError(output, "is a directory; give an .html file name")
    if not output.parent.exists():
        raise InputError(output, f"folder {output.parent} does not exist")
    err_console.print(f"[dim]building report from {bundle} ({len(b.sessions)} session file(s))…[/dim]")
    content = build_report(b, session, tracks, truth)
    html = render_html(title or f"radarcal report: {bundle.name}", content.sections, subtitle=str(bundle.resolve()), dpi=dpi)
    tmp = output.with_name(output.name + ".tmp")
    tmp.write_text(html, encoding="utf-8")
    os.replace(tmp, output)
    summary = {
        "output": str(output),
        "bytes": len(html.encode("utf-8")),
        "sections": [s.title for s in content.sections],
        "figures": content.n_figures,
        "skipped": content.skipped,
    }

    def human(s: dict) -> None:
        typer.echo(f"wrote {s['output']} ({s['bytes'] / 1e6:.2f} MB): {s['figures']} figure(s) in {len(s['sections'])} section(s)")
        for t in s["sections"]:
            typer.echo(f"  - {t}")
        for k in s["skipped"]:
            typer.echo(f"  skipped: {k}")

    emit(summary, as_json, human)
