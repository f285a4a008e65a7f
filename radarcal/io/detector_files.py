"""Files that configure a detector: the YOLO anchor config (``--anchors``) and the class names (``--names``)."""

from __future__ import annotations

import os
from pathlib import Path

from radarcal.errors import InputError, read_text

__all__ = ["read_anchor_file", "read_class_names", "class_names_from"]


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


def read_class_names(path: str | os.PathLike) -> list[str]:
    """Class names from YOLO ``data.yaml`` (``names:`` list or ``{id: name}``, checked against ``nc:``), a JSON/YAML
    list or mapping, or a text file (one name per line; ``id name`` lines are accepted)."""
    path = Path(path)
    text = read_text(path, "class names file")
    if path.suffix.lower() in (".json", ".yaml", ".yml"):
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError:
            raise InputError(path, "class names: not valid YAML/JSON") from None
        nc = data.get("nc") if isinstance(data, dict) else None
        if isinstance(data, dict) and "names" in data:
            data = data["names"]
        names = class_names_from(data)
        if not names:
            raise InputError(path, "class names: expected a list, an {id: name} mapping or a data.yaml with names:")
        if nc is not None and int(nc) != len(names):
            raise InputError(path, f"nc: {nc} but {len(names)} names")
        return names
    names = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not names:
        raise InputError(path, "class names file is empty")
    split = [n.split(None, 1) for n in names]
    if all(len(p) == 2 and p[0].isdigit() for p in split) and [int(p[0]) for p in split] == list(range(len(split))):
        names = [p[1].strip() for p in split]  # "0 red_1" lines
    return names


def class_names_from(data) -> list[str] | None:
    """Names from a list, or an ``{id: name}`` mapping with ids 0..n-1 (a model's ``names`` metadata too); else None."""
    if isinstance(data, (list, tuple)):
        return [str(v) for v in data]
    if isinstance(data, dict):
        try:
            keys = sorted(data, key=int)
        except (TypeError, ValueError):
            return None
        if [int(k) for k in keys] != list(range(len(keys))):
            return None
        return [str(data[k]) for k in keys]
    return None
