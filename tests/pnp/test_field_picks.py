"""picks.csv reader/writer and the interactive picker's logic (driven by synthetic matplotlib events)."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.field import load_field
from radarcal.pnp.picks import DEFAULT_PICKS, has_display, pick_landmarks, read_picks, write_picks


def test_roundtrip_header_comments(tmp_path):
    fm = load_field("rmuc2024")
    p = tmp_path / "p.csv"
    write_picks(p, ["blue_base", "red_outpost"], np.array([[1.25, 2.5], [300.125, 400.0]]))
    p.write_text(p.read_text() + "\n# a comment\n  \n")
    names, uv = read_picks(p, fm.landmarks)
    assert names == ["blue_base", "red_outpost"]
    np.testing.assert_allclose(uv, [[1.25, 2.5], [300.125, 400.0]])
    for side in DEFAULT_PICKS.values():
        assert all(n in fm.landmarks for n in side)


@pytest.mark.parametrize("text, words", [("a,1\n", "line 1: expected name,u,v"), ("a,x,2\n", "must be numbers"), ("a,1,2\na,3,4\n", "picked twice"), ("a,nan,2\n", "non-finite")])
def test_reader_errors(tmp_path, text, words):
    p = tmp_path / "p.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_picks(p)
    assert words in str(e.value) and str(p) in str(e.value)


def test_has_display_respects_agg(monkeypatch):
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("DISPLAY", ":0")
    assert not has_display()


def test_picker_records_clicks_skip_and_undo(monkeypatch):
    """Drive the picker with synthetic events: click, skip, undo and re-click; sub-pixel clicks come back exactly."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backend_bases import KeyEvent, MouseEvent

    fm = load_field("rmuc2024")
    names = DEFAULT_PICKS["red"]
    img = np.zeros((1024, 1280, 3), np.uint8)
    script = [("click", 100.25, 200.5), ("key", "s"), ("key", "u"), ("click", 640.0, 300.75), ("click", 900.5, 500.0), ("click", 10.0, 20.0)]

    def fake_show(*_a, **_k):
        fig = plt.gcf()
        ax = fig.axes[0]
        for ev in script:
            if ev[0] == "click":
                x, y = ax.transData.transform((ev[1], ev[2]))
                e = MouseEvent("button_press_event", fig.canvas, x, y, button=1)
                e.inaxes, e.xdata, e.ydata = ax, ev[1], ev[2]
                fig.canvas.callbacks.process("button_press_event", e)
            else:
                fig.canvas.callbacks.process("key_press_event", KeyEvent("key_press_event", fig.canvas, ev[1]))
        plt.close(fig)

    monkeypatch.setattr(plt, "show", fake_show)
    got, uv = pick_landmarks(img, names, fm)
    assert got == names
    np.testing.assert_allclose(uv, [[100.25, 200.5], [640.0, 300.75], [900.5, 500.0], [10.0, 20.0]])
