"""ONNX model files: read and written through the ``onnx`` package (protobuf); the header check that tells a model
from a wrong file before onnxruntime's unreadable error; the metadata values exporters write (``str()`` of Python
objects, or JSON). Inference engines (onnxruntime, OpenVINO) are handed the path and read the model themselves."""

from __future__ import annotations

import ast
import json
import os

__all__ = ["check_onnx_header", "parse_meta_value", "load_onnx", "save_onnx"]


def check_onnx_header(path: str | os.PathLike) -> None:
    """``ValueError`` when the file's first 64 bytes show it is no ONNX protobuf (empty, JSON / XML / text, PNG, zip);
    ``OSError`` when it cannot be read."""
    with open(path, "rb") as f:
        head = f.read(64)
    if not head or head.lstrip()[:1] in (b"{", b"<", b"#") or head[:4] in (b"\x89PNG", b"PK\x03\x04"):
        raise ValueError("not an ONNX protobuf")


def parse_meta_value(text: str):
    """A metadata string as Python/JSON literal (ultralytics writes ``str(dict)``), or the string itself."""
    for parse in (ast.literal_eval, json.loads):
        try:
            return parse(text)
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            continue
    return text


def load_onnx(path: str | os.PathLike):
    """The model as an ``onnx.ModelProto`` (needs the ``onnx`` package)."""
    import onnx

    return onnx.load(str(path))


def save_onnx(model, path: str | os.PathLike) -> None:
    """Write an ``onnx.ModelProto`` to ``path``."""
    import onnx

    onnx.save(model, str(path))
