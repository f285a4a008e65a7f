"""Entries a command stored although its own checks called the result bad (``--force``), and older entries whose
recorded checks failed: listed by ``bundle validate``, the report and ``run`` so that nobody uses them unawares.

A command that stores against its verdict records why: ``cameras.<c>.extra.forced``, ``transforms.<T>.residual.forced``
or ``runtime.hero_range_offset_forced`` (a list of reasons / a reason). Camera pairs whose field poses disagree
(:func:`radarcal.pnp.cross_check.cross_check_flags`) are listed too."""

from __future__ import annotations

__all__ = ["forced_entries"]


def _reasons(value) -> list[str]:
    if not value:
        return []
    return [str(v) for v in value] if isinstance(value, (list, tuple)) else [str(value)]


def forced_entries(bundle) -> list[str]:
    """One line per flagged entry: ``<entry>: <why it is not to be trusted>``."""
    out: list[str] = []
    for name, e in sorted(bundle.cameras.items()):
        extra = e.extra or {}
        forced = _reasons(extra.get("forced"))
        cv = extra.get("crossval") if isinstance(extra.get("crossval"), dict) else {}
        if forced:
            out.append(f"cameras.{name}: stored with --force although {'; '.join(forced)}")
        elif cv.get("consistent") is False:
            out.append(f"cameras.{name}: its cross-validation said INCONSISTENT (halves differ {cv.get('diff_median_px', float('nan')):.2f} px vs σ {cv.get('sigma_median_px', float('nan')):.2f} px)")
    for name, e in sorted(bundle.transforms.items()):
        forced = _reasons((e.residual or {}).get("forced"))
        if forced:
            out.append(f"transforms.{name}: stored with --force although {'; '.join(forced)}")
    forced = _reasons((bundle.runtime or {}).get("hero_range_offset_forced"))
    if forced:
        out.append(f"runtime.hero_range_offset_m: stored with --force although {'; '.join(forced)}")
    from radarcal.pnp.cross_check import cross_check_flags  # two cameras that disagree on the same field point

    return out + cross_check_flags(bundle)
