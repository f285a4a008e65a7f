"""Sensor source specs on the command line: ``NAME=SPEC`` (``lidar1=livox://192.168.1.50``) or a bare ``SPEC``."""

from __future__ import annotations

__all__ = ["split_named"]


def split_named(spec: str, default: str) -> tuple[str, str]:
    """``NAME=SPEC`` -> (NAME, SPEC); a bare SPEC (a path, or a URL whose query holds ``=``) gets ``default``."""
    head, sep, tail = spec.partition("=")
    if sep and "://" not in head and "/" not in head and head:
        return head, tail
    return default, spec
