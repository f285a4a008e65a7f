"""ONNX model files: the header check (wrong files refused before onnxruntime), metadata values, load / save."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.io.onnx_files import check_onnx_header, load_onnx, parse_meta_value, save_onnx
from radarcal.runtime.synthetic_onnx import make_fixed_boxes_model


@pytest.mark.parametrize("data", [b"", b'{"names": ["a"]}', b"  <?xml version='1.0'?>", b"# a text file", b"\x89PNG\r\n\x1a\n" + b"\0" * 60, b"PK\x03\x04zip"])
def test_wrong_files_are_not_onnx(tmp_path, data):
    p = tmp_path / "model.onnx"
    p.write_bytes(data)
    with pytest.raises(ValueError, match="not an ONNX protobuf"):
        check_onnx_header(p)


def test_a_model_passes_and_round_trips(tmp_path):
    pytest.importorskip("onnx")
    p = tmp_path / "m.onnx"
    make_fixed_boxes_model(p, np.zeros((4, 7), np.float32), input_size=64, names=["a", "b"])
    check_onnx_header(p)
    m = load_onnx(p)
    assert {e.key: e.value for e in m.metadata_props}["names"] == "{0: 'a', 1: 'b'}"
    save_onnx(m, tmp_path / "copy.onnx")
    assert load_onnx(tmp_path / "copy.onnx") == m
    with pytest.raises(OSError):
        check_onnx_header(tmp_path / "missing.onnx")


def test_metadata_values():
    assert parse_meta_value("{0: 'red_1', 1: 'blue_7'}") == {0: "red_1", 1: "blue_7"}  # ultralytics: str(dict)
    assert parse_meta_value("[640, 640]") == [640, 640]
    assert parse_meta_value('{"a": true}') == {"a": True}  # JSON (not a Python literal: true)
    assert parse_meta_value("Ultralytics") == "Ultralytics"
