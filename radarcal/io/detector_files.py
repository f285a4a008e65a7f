"""Files that configure a detector: the YOLO anchor config (``--anchors``)."""

from __future__ import annotations

import os

from radarcal.errors import InputError, read_text

__all__ = ["read_anchor_file"]


def read_anchor_file(path: str | os.PathLike) -> dict:
    """The anchor config YAML: a mapping with ``anchors:`` (``InputError`` otherwise)."""
    import yaml

    try:
        cfg = yaml.safe_load(read_text(path, "anchor config"))
    except yaml.YAMLError:
        raise InputError(path, "anchor config: not valid YAML") from None
    if not isinstance(cfg, dict) or "anchors" not in cfg:
        raise InputError(path, "anchor config: expected a mapping with anchors:")
    return cfg
