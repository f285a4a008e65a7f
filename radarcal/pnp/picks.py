"""Landmark picks: the ``picks.csv`` reader/writer (``name,u,v`` rows) and the interactive matplotlib picker."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from radarcal.errors import InputError

__all__ = ["read_picks", "write_picks", "has_display", "pick_landmarks", "DEFAULT_PICKS"]

# Four landmarks per side that spread over the image of a station at its own end, at different depths and heights
# (not coplanar, so the 4-point pose is unique): see docs/field.md.
DEFAULT_PICKS = {
    "red": ["blue_base", "blue_outpost", "red_outpost", "central_highland_red_south"],
    "blue": ["red_base", "red_outpost", "blue_outpost", "central_highland_blue_north"],
}


def read_picks(path: str | os.PathLike, known: dict | None = None) -> tuple[list[str], np.ndarray]:
    """Read ``name,u,v`` rows (optional header ``name,u,v``; ``#`` comments and blank lines ignored).

    ``known``: landmark names of the field model; an unknown name is an error naming the line. Returns names and
    pixels (N,2). Raises :class:`InputError` naming the file and the line for every problem."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "picks file not found (expected name,u,v rows)")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, f"cannot read picks file ({e.__class__.__name__})") from None
    names: list[str] = []
    uv: list[tuple[float, float]] = []
    for i, raw in enumerate(lines, 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        cols = [c.strip() for c in line.replace(";", ",").split(",")]
        if [c.lower() for c in cols] == ["name", "u", "v"]:
            continue
        if len(cols) != 3:
            raise InputError(path, f"line {i}: expected name,u,v, got {raw.strip()!r}")
        name = cols[0]
        try:
            u, v = float(cols[1]), float(cols[2])
        except ValueError:
            raise InputError(path, f"line {i}: u and v must be numbers, got {cols[1]!r}, {cols[2]!r}") from None
        if not (np.isfinite(u) and np.isfinite(v)):
            raise InputError(path, f"line {i}: non-finite pixel coordinate")
        if name in names:
            raise InputError(path, f"line {i}: landmark {name!r} picked twice")
        if known is not None and name not in known:
            raise InputError(path, f"line {i}: unknown landmark {name!r} (the field has: {', '.join(sorted(known))})")
        names.append(name)
        uv.append((u, v))
    return names, np.array(uv, float).reshape(-1, 2)


def write_picks(path: str | os.PathLike, names: list[str], uv: np.ndarray) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("name,u,v\n" + "".join(f"{n},{u:.3f},{v:.3f}\n" for n, (u, v) in zip(names, np.asarray(uv, float))))


def has_display() -> bool:
    """True when an interactive matplotlib window can open (a display and a non-Agg backend)."""
    backend = os.environ.get("MPLBACKEND", "").lower()
    if backend in ("agg", "pdf", "svg", "ps", "cairo", "template"):
        return False
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def pick_landmarks(image_bgr: np.ndarray, names: list[str], field_model=None) -> tuple[list[str], np.ndarray]:
    """Interactive picker: shows the image, asks for each landmark in turn (a minimap marks where it is on the field),
    a zoom panel follows the mouse for sub-pixel clicks (click in either panel). Keys: ``s`` skip (landmark not
    visible), ``u`` undo, ``q`` finish. Returns the picked names and pixels (pixel centres at integers)."""
    import matplotlib.pyplot as plt

    rgb = image_bgr[..., ::-1] if image_bgr.ndim == 3 else image_bgr
    fig = plt.figure(figsize=(14, 8))
    ax = fig.add_axes([0.02, 0.05, 0.66, 0.88])
    axz = fig.add_axes([0.70, 0.45, 0.28, 0.48])
    axm = fig.add_axes([0.70, 0.05, 0.28, 0.33])
    for a in (ax, axz):
        a.imshow(rgb, cmap="gray", interpolation="nearest")
    axz.set_xticks([])
    axz.set_yticks([])
    half = 15
    state = {"i": 0, "picked": {}, "marks": []}

    def draw_minimap() -> None:
        axm.clear()
        if field_model is not None:
            o = np.vstack([field_model.outline, field_model.outline[:1]])
            axm.plot(o[:, 0], o[:, 1], "k-", lw=1)
            for a in field_model.areas:
                p = np.vstack([a["polygon"], a["polygon"][:1]])
                axm.fill(p[:, 0], p[:, 1], color="0.8")
            for n in names:
                p = field_model.landmarks[n]
                current = state["i"] < len(names) and n == names[state["i"]]
                axm.plot(p[0], p[1], "o", color="red" if current else ("green" if n in state["picked"] else "0.5"), ms=8 if current else 4)
            axm.set_aspect("equal")
        axm.set_xticks([])
        axm.set_yticks([])

    def prompt() -> None:
        if state["i"] < len(names):
            ax.set_title(f"click {names[state['i']]}  ({state['i'] + 1}/{len(names)})   s: skip   u: undo   q: finish")
        else:
            ax.set_title("done — close the window or press q")
        draw_minimap()
        fig.canvas.draw_idle()

    def on_move(ev) -> None:
        if ev.inaxes is ax and ev.xdata is not None:
            axz.set_xlim(ev.xdata - half, ev.xdata + half)
            axz.set_ylim(ev.ydata + half, ev.ydata - half)
            fig.canvas.draw_idle()

    def on_click(ev) -> None:
        if ev.button != 1 or ev.inaxes not in (ax, axz) or ev.xdata is None or state["i"] >= len(names):
            return
        n = names[state["i"]]
        state["picked"][n] = (float(ev.xdata), float(ev.ydata))
        state["marks"].append(ax.plot(ev.xdata, ev.ydata, "r+", ms=12)[0])
        ax.annotate(n, (ev.xdata, ev.ydata), color="yellow", fontsize=8)
        state["i"] += 1
        prompt()

    def on_key(ev) -> None:
        if ev.key == "s" and state["i"] < len(names):
            state["i"] += 1
        elif ev.key == "u" and state["i"] > 0:
            state["i"] -= 1
            state["picked"].pop(names[state["i"]], None)
        elif ev.key == "q":
            plt.close(fig)
            return
        prompt()

    fig.canvas.mpl_connect("motion_notify_event", on_move)
    fig.canvas.mpl_connect("button_press_event", on_click)
    fig.canvas.mpl_connect("key_press_event", on_key)
    prompt()
    plt.show()
    got = [n for n in names if n in state["picked"]]
    return got, np.array([state["picked"][n] for n in got], float).reshape(-1, 2)
