"""Writing a generated board set (PNGs / a video + ``truth.json``, format ``radarcal-synth-board/1``) and reading its
truth back. The file I/O of the board generator; rendering is :mod:`radarcal.synth.board_render`, poses
:mod:`radarcal.synth.board_views`."""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from radarcal.board import BoardSpec, object_points
from radarcal.camera import Camera
from radarcal.geometry import invert_T

from radarcal.synth.board_render import BoardRenderer, RenderSettings, bad_view_amplitude, board_truth_pixels, bow_warp, render_blank
from radarcal.synth.board_views import BoardView, model_name, plan_views, video_trajectory

__all__ = ["write_board_set", "board_set_summary", "load_board_truth", "BoardTruth", "TRUTH_FORMAT"]

TRUTH_FORMAT = "radarcal-synth-board/1"


# ------------------------------------------------------------------------------------------------------------------
# the set writer (the only function here that touches files)
# ------------------------------------------------------------------------------------------------------------------
def _nan_to_none(a: np.ndarray) -> list:
    return [[None if not np.isfinite(x) else round(float(x), 6) for x in row] for row in np.asarray(a)]


def _write_view(out: Path, name: str, view: BoardView, rigs: list, seeds: tuple, spec: BoardSpec, bad_px: float, blur_streak: tuple[float, float]) -> dict:
    """Render one planned view through every camera of ``rigs`` ((camera, T_cami_cam0, renderer, prefix, key
    suffix)), write its PNG(s) and return its truth entry. ``seeds``: the view's seed for camera 0 and camera 1."""
    import cv2

    camera = rigs[0][0]
    entry: dict = {"kind": view.kind, "has_board": view.T_cam_board is not None, "readable": view.kind != "corrupt", "gain": round(view.gain, 6)}
    warp, amplitude = None, 0.0
    if view.kind == "bad":
        amplitude = bad_view_amplitude(camera, spec, view.T_cam_board, bad_px)
        warp = bow_warp(spec, amplitude)
        entry["bad_reason"] = f"printed pattern bowed by {amplitude * 1000:.3f} mm along y (not flat)"
        entry["bad_bow_m"] = round(amplitude, 12)
    streak, angle = 0.0, 0.0
    for cam, T_ci_cam0, renderer, prefix, sfx in rigs:
        vrng = np.random.default_rng(seeds[0] if not sfx else seeds[1])
        entry["file" + sfx] = prefix + name
        if view.T_cam_board is None:
            img = render_blank(renderer, vrng)
            entry.update({"T_cam_board" if not sfx else "T_cam1_board": None, "corners_uv" + sfx: None,
                          "visible" + sfx: None, "corner_ids" + sfx: [], "n_visible" + sfx: 0})  # fmt: skip
        else:
            T = T_ci_cam0 @ view.T_cam_board
            if view.kind == "blurred" and not sfx:
                streak = float(vrng.uniform(*blur_streak)) * cam.width
                angle = float(vrng.uniform(0, np.pi))
                entry.update(motion_blur_px=round(streak, 4), motion_blur_angle_deg=round(np.degrees(angle), 4))
            img = renderer.render(T, vrng, warp=warp, gain=view.gain, motion_blur_px=streak, motion_angle=angle)
            uv, vis = board_truth_pixels(cam, spec, T)
            entry.update({"T_cam_board" if not sfx else "T_cam1_board": np.round(T, 12).tolist(),
                          "corners_uv" + sfx: _nan_to_none(uv), "visible" + sfx: vis.tolist(),
                          "corner_ids" + sfx: np.nonzero(vis)[0].tolist(), "n_visible" + sfx: int(vis.sum())})  # fmt: skip
            if warp is not None:
                uv_a, _ = board_truth_pixels(cam, spec, T, warp=warp)
                entry["corners_uv_actual" + sfx] = _nan_to_none(uv_a)
                entry["bad_displacement_px_max" + sfx] = round(float(np.nanmax(np.linalg.norm(uv_a - uv, axis=1))), 4)
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 3])
        data = buf.tobytes()
        if view.kind == "corrupt":
            data = data[: max(64, len(data) // 3)]
        (out / (prefix + name)).write_bytes(data)
        entry["crc32" + sfx] = format(zlib.crc32(data) & 0xFFFFFFFF, "08x")
    return entry


def _truth_document(entries: list[dict], seed: int, command: str, camera: Camera, spec: BoardSpec, obj: np.ndarray, settings: RenderSettings, coverage: str) -> dict:
    """The ``truth.json`` document of a set (camera 0 part; the writer adds ``video`` and ``stereo``)."""
    return {
        "format": TRUTH_FORMAT,
        "seed": int(seed),
        "command": command,
        "model": model_name(camera),
        "camera": camera.to_dict(),
        "image_size": list(camera.image_size),
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "board": spec.to_dict(),
        "object_points": obj.tolist(),
        "render": settings.to_dict(),
        "noise": {"image_noise_sigma_dn": settings.noise_sigma, "blur_sigma_px": settings.blur_sigma,
                  "vignetting": settings.vignetting, "supersample": settings.supersample},
        "coverage": coverage,
        "files": _file_lists(entries, "file"),
        "views": entries,
    }


def _file_lists(entries: list[dict], key: str) -> dict:
    """Files of every kind (``all``, ``board``, ``full`` ...) from the entries' ``key`` (``file`` / ``file_cam1``)."""
    kinds = ("full", "partial", "bad", "blurred", "blank", "corrupt")
    lists = {"all": [e[key] for e in entries], "board": [e[key] for e in entries if e["kind"] in ("full", "partial", "bad", "blurred")]}
    lists.update({k: [e[key] for e in entries if e["kind"] == k] for k in kinds})
    return lists


def write_board_set(out_dir: str | os.PathLike, camera: Camera, spec: BoardSpec, n_views: int = 25, seed: int = 0,
                    settings: RenderSettings = RenderSettings(), coverage: str = "full", n_partial: int = 2,
                    n_blank: int = 2, n_corrupt: int = 1, bad_view: bool = False, bad_px: float = 1.5,
                    n_blurred: int = 0, blur_streak: tuple[float, float] = (0.01, 0.016),
                    stereo: tuple[Camera, np.ndarray] | None = None, video_seconds: float = 0.0, video_fps: float = 10.0,
                    command: str = "", progress=None) -> dict:
    """Write ``n_views`` board PNGs (+ blank and corrupt files) and ``truth.json`` into ``out_dir``; return the truth.

    Deterministic: the same arguments give bit-identical files. The corrupt file is a rendered board PNG
    truncated to a third of its bytes. ``bad_view`` bows the printed pattern of one view (see :func:`bow_warp`) so
    that its corners sit up to ``bad_px`` pixels away from where a flat board would put them. ``n_blurred`` views get
    a motion streak in a random direction, its length drawn from ``blur_streak`` x image width (12.8-20 px at 1280
    px): symmetric, so the true corners do not move, but detections on such views are poor.

    ``stereo=(camera1, T_cam1_cam0)``: every view is also rendered through a second camera; images go to
    ``cam0/img_NNN.png`` and ``cam1/img_NNN.png`` (same name = same instant) and the truth gains a ``stereo`` block
    and ``*_cam1`` keys per view. Mono sets (the default) write ``img_NNN.png`` at the top level.

    ``video_seconds > 0`` also writes ``video.avi`` (MJPG, camera 0): the board moving smoothly through the full
    views' poses, dwelling at each, motion-blurred in proportion to its speed; per-frame truth under ``video``.
    """

    if spec.legacy is None:  # "decide automatically" means nothing to a renderer: it draws the new layout
        spec = replace(spec, legacy=False)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (out / "truth.json").is_file():  # a previous set lives here: drop its images so no stale file survives
        for pattern in ("img_[0-9][0-9][0-9].png", "cam[01]/img_[0-9][0-9][0-9].png", "video.avi"):
            for old in out.glob(pattern):
                old.unlink()
    prefix0, prefix1 = ("cam0/", "cam1/") if stereo is not None else ("", "")
    for prefix in {prefix0, prefix1} - {""}:
        (out / prefix).mkdir(exist_ok=True)
    root = np.random.SeedSequence(int(seed))
    plan_seed, *view_seeds = root.spawn(1 + n_views + n_blank + n_corrupt)
    rng = np.random.default_rng(plan_seed)
    views = plan_views(camera, spec, n_views, rng, coverage, n_partial=n_partial, n_bad=1 if bad_view else 0,
                       n_blurred=n_blurred, also_full_in=stereo)
    # corrupt files are rendered board views too (then truncated); blanks have no board
    extra_corrupt = plan_views(camera, spec, n_corrupt, rng, coverage, n_partial=0, also_full_in=stereo) if n_corrupt else []
    for v in extra_corrupt:
        v.kind = "corrupt"
    all_views = views + [BoardView("blank", None, float(rng.uniform(0.9, 1.06))) for _ in range(n_blank)] + extra_corrupt
    order = rng.permutation(len(all_views))
    rigs = [(camera, np.eye(4), BoardRenderer(camera, spec, settings), prefix0, "")]
    stereo_seeds: list = []
    if stereo is not None:
        cam1, T_cam1_cam0 = stereo[0], np.asarray(stereo[1], float)
        rigs.append((cam1, T_cam1_cam0, BoardRenderer(cam1, spec, settings), prefix1, "_cam1"))
        stereo_seeds = np.random.SeedSequence([int(seed), 1]).spawn(len(all_views))
    obj = object_points(spec)
    entries = []
    iterator = range(len(order)) if progress is None else progress(range(len(order)))
    for i in iterator:
        seeds = (view_seeds[order[i]], stereo_seeds[order[i]] if stereo is not None else None)
        entries.append(_ordered_entry(_write_view(out, f"img_{i:03d}.png", all_views[order[i]], rigs, seeds, spec, bad_px, blur_streak)))

    truth = _truth_document(entries, seed, command, camera, spec, obj, settings, coverage)
    if video_seconds > 0:
        keyviews = [j for j, v in enumerate(views) if v.kind == "full"] or list(range(len(views)))
        if keyviews:
            file_of = {int(j): entries[i]["file"] for i, j in enumerate(order)}
            truth["video"] = _write_video(out, rigs[0][2], spec, [views[j].T_cam_board for j in keyviews],
                                          video_seconds, video_fps, seed)
            truth["video"]["keyframe_files"] = [file_of[j] for j in keyviews][: len(truth["video"]["keyframes"])]
    if stereo is not None:
        cam1, T10 = rigs[1][0], rigs[1][1]
        truth["stereo"] = {"model1": model_name(cam1), "camera1": cam1.to_dict(), "T_cam1_cam0": np.round(T10, 12).tolist(),
                           "baseline_m": round(float(np.linalg.norm(invert_T(T10)[:3, 3])), 12), "files1": _file_lists(entries, "file_cam1")}
    tmp = out / "truth.json.tmp"
    tmp.write_text(json.dumps(truth, indent=1) + "\n")
    tmp.replace(out / "truth.json")
    return truth


def _write_video(out: Path, renderer: BoardRenderer, spec: BoardSpec, keyposes: list[np.ndarray], seconds: float,
                 fps: float, seed: int, exposure: float = 0.5) -> dict:
    """Render the trajectory through ``keyposes`` as ``video.avi`` (MJPG); return its truth block."""
    import cv2

    cam = renderer.camera
    n_seg = max(1, len(keyposes) - 1)
    per_seg = max(1, int(round((seconds * fps - 1) / n_seg)))
    n = per_seg * n_seg + 1  # ~seconds * fps frames, with every key pose exactly on a frame
    poses, keys = video_trajectory(spec, keyposes, n)
    centre = spec.centre[None, :]
    # image motion of the board centre while the shutter is open (exposure x frame interval, centred on the frame)
    before = video_trajectory(spec, keyposes, n, offset=-exposure / 2)[0]
    after = video_trajectory(spec, keyposes, n, offset=+exposure / 2)[0]
    motion = np.array([cam.project_from(a, centre)[0][0] - cam.project_from(b, centre)[0][0] for b, a in zip(before, after)])
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2]))
    writer = cv2.VideoWriter(str(out / "video.avi"), cv2.VideoWriter_fourcc(*"MJPG"), float(fps), cam.image_size, isColor=False)
    if not writer.isOpened():  # pragma: no cover - OpenCV builds without a video backend
        raise OSError("cannot open an MJPG video writer")
    frames = []
    try:
        for i, T in enumerate(poses):
            streak = float(np.hypot(*motion[i])) if np.all(np.isfinite(motion[i])) else 0.0
            angle = float(np.arctan2(motion[i][1], motion[i][0])) if streak > 0 else 0.0
            streak = streak if streak >= 1.0 else 0.0
            writer.write(renderer.render(T, rng, motion_blur_px=streak, motion_angle=angle))
            _, vis = board_truth_pixels(cam, spec, T)
            frames.append({"T_cam_board": np.round(T, 12).tolist(), "n_visible": int(vis.sum()),
                           "motion_blur_px": round(streak, 4), "keyframe": bool(i in set(keys.tolist()))})
    finally:
        writer.release()
    return {"file": "video.avi", "codec": "MJPG", "fps": float(fps), "n_frames": n, "exposure_fraction": exposure,
            "keyframes": keys.tolist(), "frames": frames}


_ENTRY_ORDER = ("file", "kind", "has_board", "readable", "gain", "T_cam_board", "corners_uv", "visible", "corner_ids",
                "n_visible", "corners_uv_actual", "bad_reason", "bad_bow_m", "bad_displacement_px_max", "motion_blur_px",
                "motion_blur_angle_deg", "crc32")


def _ordered_entry(entry: dict) -> dict:
    """Stable key order in truth.json: camera-0 keys first (as in mono sets), then the ``*_cam1`` keys."""
    first = {k: entry[k] for k in _ENTRY_ORDER if k in entry}
    return first | {k: v for k, v in entry.items() if k not in first}


@dataclass
class BoardTruth:
    """A parsed ``truth.json`` of a board set (see docs/synth.md for the keys)."""

    folder: Path
    camera: Camera
    spec: BoardSpec
    object_points: np.ndarray  # (N, 3)
    views: list[dict]  # as stored, plus numpy arrays: "uv" (N, 2; NaN = not projectable), "vis" (N,), "T" (4x4 or None)
    raw: dict

    def files(self, kind: str = "all") -> list[Path]:
        """Paths of the files of one kind (all | board | full | partial | bad | blurred | blank | corrupt)."""
        return [self.folder / f for f in self.raw["files"].get(kind, [])]


def load_board_truth(path: str | os.PathLike) -> BoardTruth:
    """Read a set's ``truth.json`` (path to the file or to its folder)."""
    path = Path(path)
    file = path / "truth.json" if path.is_dir() else path
    raw = json.loads(file.read_text())
    if raw.get("format") != TRUTH_FORMAT:
        raise ValueError(f"{file}: not a {TRUTH_FORMAT} truth file (format {raw.get('format')!r})")
    views = []
    for v in raw["views"]:
        v = dict(v)
        if v.get("corners_uv") is not None:
            v["uv"] = np.array([[np.nan if x is None else x for x in row] for row in v["corners_uv"]], float)
            v["vis"] = np.asarray(v["visible"], bool)
        v["T"] = None if v.get("T_cam_board") is None else np.asarray(v["T_cam_board"], float)
        views.append(v)
    return BoardTruth(file.parent, Camera.from_dict(raw["camera"]), BoardSpec.from_dict(raw["board"]),
                      np.asarray(raw["object_points"], float), views, raw)


def board_set_summary(truth: dict, out_dir: str | Path, seconds: float) -> dict:
    """What ``radarcal synth board`` reports of a written set: camera, board, files by kind, video and stereo parts."""
    files = truth["files"]
    summary = {
        "out_dir": str(out_dir),
        "truth": str(Path(out_dir) / "truth.json"),
        "model": truth["model"],
        "camera": truth["camera"],
        "board": truth["board"],
        "n_files": len(files["all"]),
        "files": {k: v for k, v in files.items() if k != "all"},
        "seconds": round(seconds, 2),
    }
    if "video" in truth:
        summary["video"] = {k: truth["video"][k] for k in ("file", "fps", "n_frames", "keyframes")}
    if "stereo" in truth:
        summary["stereo"] = {k: v for k, v in truth["stereo"].items() if k != "files1"}
    return summary
