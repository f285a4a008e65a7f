"""``radarcal report BUNDLE [--session DIR] [--tracks FILE [--truth FILE]] -o report.html``: one self-contained HTML
page with every figure the bundle's session files allow (see docs/report.md)."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit, err_console
from radarcal.cli.outputs import check_outputs, input_file
from radarcal.errors import InputError


def _check_tracks(path: Path, what: str) -> None:
    """A track file the report can draw: JSON lines with robot positions, all finite (InputError naming it)."""
    import numpy as np

    from radarcal.errors import read_text
    from radarcal.report.build import read_tracks

    input_file(path, what)
    read_text(path, what)  # undecodable bytes -> one line naming the file
    _t, xyz = read_tracks(path)
    if not xyz:
        raise InputError(path, f"no robot positions in the {what} (expected JSON lines {{\"t\", \"robots\": [{{\"label\", \"x\", \"y\"}}]}} as written by radarcal run --out)")
    if not all(np.all(np.isfinite(p)) for p in xyz.values()) or not all(np.all(np.isfinite(t)) for t in _t.values()):
        raise InputError(path, f"non-finite time or position in the {what}")


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
    from radarcal.verdicts import forced_entries

    b = load_bundle(bundle)
    for path, what in ((tracks, "track file"), (truth, "truth track file")):
        if path is not None:
            _check_tracks(path, what)
    if session is not None and not session.is_dir():
        raise InputError(session, "session folder not found" if not session.exists() else "is not a folder (give the folder of session .npz files)")
    check_outputs(bundle, [("report", output)], b, inputs=[tracks, truth])
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
        "warnings": forced_entries(b),
    }

    def human(s: dict) -> None:
        typer.echo(f"wrote {s['output']} ({s['bytes'] / 1e6:.2f} MB): {s['figures']} figure(s) in {len(s['sections'])} section(s)")
        for t in s["sections"]:
            typer.echo(f"  - {t}")
        for k in s["skipped"]:
            typer.echo(f"  skipped: {k}")
        for w in s["warnings"]:
            typer.echo(f"  warning: {w}")

    emit(summary, as_json, human)
