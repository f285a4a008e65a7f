"""Where ``field-pnp``'s picks come from: a ``picks.csv`` file, the matplotlib picker on ``--image``, or the browser
page (``--ui``). Returns exactly what the CSV path gives (names, pixels), so every source meets the same solver."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from radarcal.errors import InputError

__all__ = ["Picks", "acquire_picks"]


@dataclass
class Picks:
    names: list[str]
    uv: np.ndarray  # (N,2) px
    source: Path  # the picks file (read, or written by the picker)
    T_nudged: np.ndarray | None = None  # T_cam_field the operator nudged in the browser, if any


def _wanted(fm, landmarks: str | None, side: str) -> list[str]:
    from radarcal.pnp.picks import DEFAULT_PICKS

    want = [s.strip() for s in landmarks.split(",")] if landmarks else DEFAULT_PICKS[side]
    unknown = [n for n in want if n not in fm.landmarks]
    if unknown:
        raise InputError("--landmarks", f"unknown landmark(s) {', '.join(unknown)} (the field has: {', '.join(sorted(fm.landmarks))})")
    return want


def _check_image(image: Path, cam, camera: str) -> np.ndarray:
    from radarcal.io import read_image

    img = read_image(image)
    if tuple(img.shape[1::-1]) != tuple(cam.image_size):
        raise InputError(image, f"image is {img.shape[1]}x{img.shape[0]} but camera {camera} is {cam.width}x{cam.height}")
    return img


def acquire_picks(cam, camera: str, fm, points: Path | None, image: Path | None, landmarks: str | None, side: str, ui: str | None,
                  check: Callable, check_picks_output: Callable, T_init: np.ndarray | None = None, options=None, log: Callable = print) -> Picks:
    """The picks of one run. ``check(names, uv, T_override) -> dict`` validates a browser save (same solver and checks);
    ``check_picks_output(path)`` refuses a picks file that may not be written; ``log``: progress lines (stderr)."""
    from radarcal.pnp.picks import has_display, pick_landmarks, read_picks, save_picks

    if image is not None:
        img = _check_image(image, cam, camera)
    if ui is not None:  # the browser page (radarcal/pnp/ui.py): saving runs the same solver and checks as the CSV path
        if image is None:
            raise InputError("--ui", "needs --image (the camera frame to click on)")
        from radarcal.pnp.ui import pick_in_browser

        want = _wanted(fm, landmarks, side)
        src = points or image.with_suffix(".picks.csv")
        start = dict(zip(*read_picks(points, fm.landmarks))) if points is not None and points.exists() else {}
        names, uv, T_nudged = pick_in_browser(img, cam, fm, want, check, ui, T_init=T_init, options=options, initial=start)
        save_picks(src, names, uv)
        log(f"wrote {len(names)} picks to {src}")
        return Picks(*read_picks(src, fm.landmarks), src, T_nudged)  # from here on exactly the CSV path
    if points is not None and points.exists():
        return Picks(*read_picks(points, fm.landmarks), points)
    if image is None:
        if points is not None:
            raise InputError(points, "picks file not found (expected name,u,v rows; or pass --image to click them)")
        raise InputError("--points", "pass --points picks.csv (name,u,v rows) or --image IMG to click the landmarks")
    src = points or image.with_suffix(".picks.csv")
    if not has_display():
        if points is not None or not src.is_file():
            raise InputError("--image", "no usable display for the interactive picker (headless, or no GUI toolkit); click the landmarks elsewhere and pass --points picks.csv (name,u,v rows)")
        log(f"no usable display for the picker: using the picks saved earlier in {src}")
        return Picks(*read_picks(src, fm.landmarks), src)
    want = _wanted(fm, landmarks, side)
    check_picks_output(src)
    names, uv = pick_landmarks(img, want, fm)
    save_picks(src, names, uv)
    log(f"wrote {len(names)} picks to {src}")
    return Picks(names, uv, src)
