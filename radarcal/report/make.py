"""``radarcal report`` as one call: :func:`make_report` checks the inputs, builds the sections
(:func:`radarcal.report.build.build_report`), renders the page and writes it atomically; :class:`ReportResult` is what
the command prints."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from radarcal.bundle import Bundle
from radarcal.errors import InputError

__all__ = ["ReportResult", "check_report_inputs", "make_report"]


@dataclass
class ReportResult:
    output: str
    bytes: int
    sections: list[str]
    figures: int
    skipped: list[str] = field(default_factory=list)  # what could not be drawn (or was drawn without something) and why
    warnings: list[str] = field(default_factory=list)  # results stored against the tool's own verdict (--force)

    def to_dict(self) -> dict:
        return {"output": self.output, "bytes": self.bytes, "sections": list(self.sections), "figures": self.figures, "skipped": list(self.skipped), "warnings": list(self.warnings)}


def check_report_inputs(session: Path | None = None, tracks: Path | None = None, truth: Path | None = None) -> None:
    """Everything the report reads besides the bundle, checked before any work (``InputError`` naming the file):
    ``--truth`` needs ``--tracks``; track files readable with robot positions; the session folder a folder."""
    from radarcal.report.field_section import read_tracks

    if truth is not None and tracks is None:
        raise InputError(truth, "--truth needs --tracks (the truth is compared with a run's track file; give --tracks FILE too)")
    for path, what in ((tracks, "track file"), (truth, "truth track file")):
        if path is not None:
            read_tracks(path, what)
    if session is not None and not Path(session).is_dir():
        raise InputError(session, "session folder not found" if not Path(session).exists() else "is not a folder (give the folder of session .npz files)")


def make_report(bundle: Bundle, output: str | os.PathLike, session: Path | None = None, tracks: Path | None = None, truth: Path | None = None, title: str = "", dpi: int = 96) -> ReportResult:
    """The report of ``bundle`` (its sessions, optionally a run's tracks against the truth) written to ``output`` as
    one self-contained HTML page (temp file + rename: a failed run leaves no half page)."""
    from radarcal.report.build import build_report
    from radarcal.report.html import render_html
    from radarcal.verdicts import forced_entries

    check_report_inputs(session, tracks, truth)
    output = Path(output)
    name = bundle.path.name if bundle.path else "bundle"
    content = build_report(bundle, session, tracks, truth)
    html = render_html(title or f"radarcal report: {name}", content.sections, subtitle=str(bundle.path.resolve()) if bundle.path else "", dpi=dpi)
    tmp = output.with_name(output.name + ".tmp")
    try:
        tmp.write_text(html, encoding="utf-8")
        os.replace(tmp, output)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise InputError(output, f"cannot write the report ({e.strerror or e.__class__.__name__})") from None
    return ReportResult(str(output), len(html.encode("utf-8")), [s.title for s in content.sections], content.n_figures, list(content.skipped), forced_entries(bundle))
