"""The replay folder's files: truth.jsonl read lazily."""

from __future__ import annotations

import pytest

from radarcal.io.replay import TruthLines


def test_truth_lines_are_lazy_and_resumable(tmp_path):
    p = tmp_path / "truth.jsonl"
    p.write_text('{"frame": "a", "robots": []}\n\n  \n{"frame": "b", "robots": [1]}\n{"frame": "c"}\n', encoding="utf-8")
    lines = TruthLines(p)
    assert next(lines)["frame"] == "a"
    for d in lines:  # leaving a loop and coming back resumes where it stopped
        if d["frame"] == "b":
            break
    assert [d["frame"] for d in lines] == ["c"] and list(lines) == []
    lines.close()
    with pytest.raises(ValueError):
        next(lines)
