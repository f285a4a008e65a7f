"""Every command, every file it reads or writes, through the bad-input matrix (issue #16 item 5).

For each (command, file option, kind of bad file) the command runs in-process through ``radarcal.cli.main.main``
with a minimal valid argument set in which only that one file is bad, and must answer with exactly one line
``error: <the file>: <problem>``, exit code 2, no traceback, and leave the bundle's bytes and mode as they were.

Kinds (inputs): missing, empty, directory, binary, non-UTF-8, NaN/inf values, wrong header. Outputs: a folder that
does not exist, a read-only folder, the output being a folder, the output being the bundle.

Commands are discovered from the typer app: a command (or a path option of one) missing from :data:`TABLE` fails
:func:`test_every_command_and_file_option_is_in_the_table`, so a command added later gets a row here.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from radarcal.cli.main import app, main

REPO = Path(__file__).resolve().parents[2]


# --- the table ---------------------------------------------------------------------------------------------------
@dataclass
class Opt:
    """One file the command names. ``flag`` is the option (None: a positional, ``index`` into the base args);
    ``fmt`` picks the bad contents; ``role`` input | output | folder_in | folder_out | bundle."""

    flag: str | None
    fmt: str
    role: str = "input"
    index: int | None = None
    skip: tuple[str, ...] = ()  # kinds that are legitimately accepted for this file (why: in ``why``)
    why: str = ""
    extra: Callable[[dict], list] | None = None  # options this file needs to be read at all
    base: Callable[[dict], list] | None = None  # another minimal argument set for this file (instead of the command's)


@dataclass
class Cmd:
    base: Callable[[dict], list[str]]  # minimal valid argument list (without the command words)
    opts: list[Opt]
    bundle: Callable[[dict], Path] | None = None  # the bundle whose bytes/mode must survive
    creates_bundle: bool = False  # a missing bundle is created (not an error)
    not_files: tuple[str, ...] = ()  # path parameters that are not files the user supplies (documented)


def _b(f):
    return f["bundle"]


TABLE: dict[str, Cmd] = {
    "bundle show": Cmd(lambda f: [f["bundle"]], [Opt(None, "bundle", "bundle", index=0)], _b),
    "bundle validate": Cmd(lambda f: [f["bundle"]], [Opt(None, "bundle", "bundle", index=0)], _b),
    "bundle import": Cmd(lambda f: [f["bundle"], f["camera_json"], "--camera", "camX"],
                         [Opt(None, "bundle", "bundle", index=0), Opt(None, "camera", index=1)], _b, creates_bundle=True),
    "bundle export": Cmd(lambda f: [f["bundle"], "--camera", "cam0", "-o", f["tmp"] / "out.yaml"],
                         [Opt(None, "bundle", "bundle", index=0), Opt("-o", "text", "output")], _b),
    "bundle set-transform": Cmd(lambda f: [f["bundle"], "cam9", "lidar9", f["transform"]],
                                [Opt(None, "bundle", "bundle", index=0), Opt(None, "transform", index=3)], _b, creates_bundle=True),
    "intrinsics": Cmd(lambda f: [f["board_images"], "--cols", "9", "--rows", "6", "--square", "0.025", "-b", f["bundle"], "--no-crossval"],
                      [Opt(None, "image", "input", index=0, skip=("nan", "header"), why="a list of image sources (no numbers, no header)"),
                       Opt("--bundle", "bundle", "bundle"), Opt("--right", "image", skip=("nan", "header"), why="image sources (no numbers, no header)"),
                       Opt("--corners", "icorners", base=lambda f: ["--corners", f["icorners"], "--image-size", "640x480", "--cols", "9", "--rows", "6", "--square", "0.025", "-b", f["bundle"], "--no-crossval"])],
                      _b, creates_bundle=True),
    "lidar-camera": Cmd(lambda f: ["-b", f["bundle"], "--image", f["image"], "--cloud", f["cloud"], "--corners", f["corners"]],
                        [Opt("--bundle", "bundle", "bundle"), Opt("--image", "image"), Opt("--cloud", "cloud"), Opt("--corners", "corners"),
                         Opt("--init", "transform"), Opt("--board-uv", "uv", extra=lambda f: ["--board", "1.0,0.8"]), Opt("--overlay", "image", "output")], _b, creates_bundle=True),
    "field-pnp": Cmd(lambda f: ["-b", f["bundle"], "--points", f["picks"]],
                     [Opt("--bundle", "bundle", "bundle"), Opt("--points", "picks"), Opt("--image", "image"), Opt("--field", "field"),
                      Opt("--error-map", "image", "output"), Opt("--overlay", "image", "output")], _b),
    "radar-lidar": Cmd(lambda f: [f["radar_session"], "-b", f["bundle"]],
                       [Opt(None, "radar_session", "folder_in", index=0), Opt("--bundle", "bundle", "bundle")], _b, creates_bundle=True),
    "run": Cmd(lambda f: ["--replay", f["replay"], "--bundle", f["bundle"], "-q", "--max-frames", "2"],
               [Opt("--bundle", "bundle", "bundle"), Opt("--replay", "replay", "folder_in"), Opt("--detections", "detections"),
                Opt("--detector", "onnx", skip=("nan", "header"), why="an ONNX model: binary, no numbers in text"),
                Opt("--names", "names", skip=("nan", "header", "empty"), why="class names: any text is names; an empty file means the model's own",
                    extra=lambda f: ["--detector", f["onnx"]]),
                Opt("--armour", "onnx", skip=("nan", "header"), why="an ONNX model: binary, no numbers in text", extra=lambda f: ["--detector", f["onnx"]]),
                Opt("--number", "onnx", skip=("nan", "header"), why="an ONNX model: binary, no numbers in text", extra=lambda f: ["--detector", f["onnx"]]),
                Opt("--armour-names", "names", skip=("nan", "header", "empty"), why="class names: any text is names; an empty file means the model's own",
                    extra=lambda f: ["--detector", f["onnx"], "--armour", f["onnx"]]),
                Opt("--number-names", "names", skip=("nan", "header", "empty"), why="class names: any text is names; an empty file means the model's own",
                    extra=lambda f: ["--detector", f["onnx"], "--number", f["onnx"]]),
                Opt("--anchors", "names", skip=("header",), why="a YAML mapping; any key order", extra=lambda f: ["--detector", f["onnx"]]),
                Opt("--out", "text", "output"), Opt("--minimap", "image", "output")], _b,
               not_files=("--video", "--clouds", "--record")),  # --record: a live run only (tests/cli/test_record_replay.py)
    "hero-offset": Cmd(lambda f: ["-b", f["bundle"], "--replay", f["replay"], "--actual", "10"],
                       [Opt("--bundle", "bundle", "bundle"), Opt("--replay", "replay", "folder_in")], _b),
    "report": Cmd(lambda f: [f["bundle"], "-o", f["tmp"] / "r.html"],
                  [Opt(None, "bundle", "bundle", index=0), Opt("-o", "text", "output"), Opt("--tracks", "tracks"), Opt("--truth", "tracks"),
                   Opt("--session", "session", "folder_in", skip=("empty",), why="an empty session folder is a report without figures")], _b),
    "synth board": Cmd(lambda f: [f["tmp"] / "board_out", "--views", "1", "--blank", "0", "--corrupt", "0", "--image-size", "64x48", "--supersample", "1"],
                       [Opt(None, "board_out", "folder_out", index=0), Opt("--camera-file", "camera")]),
    "synth lidar-camera": Cmd(lambda f: ["-o", f["tmp"] / "lc_out", "--duration", "0.01", "--rate", "1000"],
                              [Opt("-o", "lc_out", "folder_out")]),
    "synth field": Cmd(lambda f: [f["tmp"] / "field_out", "--frames", "1", "--robots", "0", "--lidar-points", "10", "--image-scale", "0.05"],
                       [Opt(None, "field_out", "folder_out", index=0), Opt("--field", "field")]),
    "lidar-field": Cmd(lambda f: ["-b", f["bundle"], "--cloud", f["cloud"], "--field", "rmuc2024", "--init", f["transform"]],
                       [Opt("--bundle", "bundle", "bundle"), Opt("--cloud", "cloud"), Opt("--init", "transform"),
                        Opt("--field-mesh", "cloud", skip=("nan", "header"), why="a mesh file (STL/PLY/OBJ): the PCD variants do not apply",
                            base=lambda f: ["-b", f["bundle"], "--cloud", f["cloud"], "--init", f["transform"]])], _b, creates_bundle=True),
    "synth match": Cmd(lambda f: [f["tmp"] / "match_out", "--frames", "1", "--robots", "0", "--people", "0", "--lidar-points", "100", "--no-aerial"],
                       [Opt(None, "match_out", "folder_out", index=0)]),
    # live-sensor commands: they need a running LiDAR (simulator) before any file is read; their inputs are covered by
    # tests/cli/test_record_replay.py and tests/io/test_livox.py, not by this matrix
    "record": Cmd(lambda f: [], [], not_files=("OUT", "out", "--bundle", "-b")),
    "synth livox-sim": Cmd(lambda f: [], [], not_files=("--scene",)),
    "referee-sim": Cmd(lambda f: ["--replay", f["replay"], "--season", "2026", "--start-timeout", "0.1"],
                       [Opt("--replay", "replay", "folder_in"),
                        Opt("--record", "text", "output", skip=("is-bundle",), why="referee-sim reads no bundle (the replay's own files are protected)")]),
    "quantise": Cmd(lambda f: [f["onnx"], "--images", f["replay"], "-o", f["tmp"] / "q.onnx"],
                    [Opt(None, "onnx", index=0, skip=("nan", "header"), why="an ONNX model: binary, no numbers in text"), Opt("--images", "replay", "folder_in"),
                     Opt("--held-out", "replay", "folder_in"), Opt("-o", "text", "output", skip=("is-bundle",), why="quantise reads no bundle")]),
    "synth radar": Cmd(lambda f: [f["tmp"] / "radar_out", "--scenes", "1"], [Opt(None, "radar_out", "folder_out", index=0)]),
}

INPUT_KINDS = ("missing", "empty", "directory", "binary", "non-utf8", "nan", "header")
FOLDER_IN_KINDS = ("missing", "file", "empty")
OUTPUT_KINDS = ("no-folder", "read-only", "is-folder", "is-bundle")
FOLDER_OUT_KINDS = ("is-file", "read-only")


# --- discovery -----------------------------------------------------------------------------------------------------
def _commands() -> dict:
    import typer

    root = typer.main.get_command(app)
    out: dict = {}

    def walk(cmd, prefix):
        if hasattr(cmd, "commands"):  # a group (typer may vendor its own click: no isinstance)
            for name, sub in cmd.commands.items():
                walk(sub, [*prefix, name])
        else:
            out[" ".join(prefix)] = cmd

    walk(root, [])
    return out


def _is_path(p) -> bool:
    """A parameter typed as a path (click.Path, or typer >= 0.2x's type descriptor of a ``Path`` / ``list[Path]``)."""
    import typing

    if type(getattr(p, "type", None)).__name__ == "Path":
        return True
    ann = getattr(getattr(p, "type_descriptor", None), "annotation", None)
    return ann is Path or (typing.get_origin(ann) is list and typing.get_args(ann) == (Path,))


def _is_option(p) -> bool:
    return getattr(p, "param_type_name", "") == "option"


def test_every_command_and_file_option_is_in_the_table():
    cmds = _commands()
    missing = sorted(set(cmds) - set(TABLE))
    assert not missing, f"commands without a row in TABLE (add their file options and a minimal valid argument set): {missing}"
    gaps = {}
    for name, cmd in cmds.items():
        spec = TABLE[name]
        listed = set(spec.not_files)
        for o in spec.opts:
            if o.flag is not None:
                listed |= {x for p in cmd.params if _is_option(p) and o.flag in p.opts for x in p.opts}
        positional = [p.name for p in cmd.params if not _is_option(p)]
        listed |= {positional[o.index] for o in spec.opts if o.flag is None and o.index is not None and o.index < len(positional)}
        for p in cmd.params:
            flags = set(p.opts) if _is_option(p) else {p.name}
            if _is_path(p) and not flags & listed:
                gaps.setdefault(name, []).append(max(flags, key=len))
    assert not gaps, f"path parameters not in TABLE: {gaps}"


# --- fixtures: one small valid world -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Valid files for every option (tiny): a 1-frame generated replay (bundle, image, cloud, detections), a camera
    file, a transform, corners, board corners, picks, a track file, a radar session, an ONNX model."""
    from radarcal.bundle import load_bundle
    from radarcal.field import load_field
    from radarcal.synth.field import FieldSceneConfig, write_field_replay

    root = tmp_path_factory.mktemp("world")
    rep = root / "replay"
    write_field_replay(rep, load_field("rmuc2024"), FieldSceneConfig(frames=3, seed=4, robots=2, lidar_points=400, image_scale=0.1))
    truth = json.loads((rep / "truth.json").read_text())
    b = load_bundle(rep / "calib.yaml")
    cam = b.camera("cam0")
    w = {"replay": rep, "image": rep / "images" / "000000.jpg", "cloud": next((rep / "clouds").glob("*.pcd"))}
    w["camera"] = w["camera_json"] = root / "cam.json"
    assert main(["bundle", "export", str(rep / "calib.yaml"), "--camera", "cam0", "--format", "json", "-o", str(w["camera_json"])]) == 0
    w["transform"] = root / "T.txt"
    w["transform"].write_text("0.1 0 0 0 0 90\n")
    T = b.T("cam0", "lidar0")
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(5, 12, 10), rng.uniform(-2, 2, 10), rng.uniform(-1, 1, 10)])
    uv, _, _ = cam.project_from(T, p)
    w["corners"] = root / "corners.csv"
    w["corners"].write_text("x,y,z,u,v\n" + "".join(f"{a:.6f},{c:.6f},{d:.6f},{u:.3f},{v:.3f}\n" for (a, c, d), (u, v) in zip(p, uv)))
    w["uv"] = root / "uv.csv"
    w["uv"].write_text("u,v\n" + "".join(f"{u:.3f},{v:.3f}\n" for u, v in uv[:4]))
    names = ["blue_base", "blue_outpost", "red_outpost", "central_highland_red_south"]
    w["picks"] = root / "picks.csv"
    w["picks"].write_text("name,u,v\n" + "".join(f"{n},{truth['landmark_pixels'][n][0]:.3f},{truth['landmark_pixels'][n][1]:.3f}\n" for n in names))
    w["field"] = root / "field.yaml"
    import yaml

    w["field"].write_text(yaml.safe_dump(load_field("rmuc2024").to_dict()))
    w["tracks"] = root / "tracks.jsonl"
    assert main(["run", "--replay", str(rep), "--out", str(w["tracks"]), "-q", "--max-frames", "2"]) == 0
    w["detections"] = rep / "detections.jsonl"
    w["radar_session"] = root / "radar"
    assert main(["synth", "radar", str(w["radar_session"]), "--scenes", "2"]) == 0
    from radarcal.runtime.synthetic_onnx import make_fixed_boxes_model

    w["onnx"] = root / "m.onnx"
    make_fixed_boxes_model(w["onnx"], np.zeros((1, 7), np.float32), 640, ["blue_1", "red_1"])
    w["names"] = root / "names.txt"
    w["names"].write_text("blue_1\nred_1\n")
    w["session"] = rep / "calib.sessions"
    w["board_images"] = REPO / "datasets" / "synth_board_640"
    w["text"] = root / "out.txt"
    w["icorners"] = root / "corners_ids.csv"  # intrinsics --corners: image,id,u,v (3 views of the 9x6 board)
    w["icorners"].write_text("image,id,u,v\n" + "".join(f"v{k}.png,{i},{100 + 30 * (i % 9) + 7 * k:.2f},{100 + 30 * (i // 9) + 3 * k:.2f}\n" for k in range(3) for i in range(54)))
    return w


# --- bad files ----------------------------------------------------------------------------------------------------
GOOD_TEXT_FORMATS = {"bundle", "camera", "transform", "corners", "icorners", "uv", "picks", "field", "tracks", "detections", "names", "text"}


def _nan_variant(fmt: str, good: str) -> str:
    if fmt == "bundle":
        return good.replace("K:\n", "K:\n", 1).replace("- [", "- [.nan, ", 1) if "- [" in good else good + "\nruntime: {hero_range_offset_m: .nan}\n"
    if fmt in ("camera", "tracks", "detections"):
        import re

        return re.sub(r"(?<![\w.])-?\d+\.\d+", "NaN", good, count=3)
    if fmt == "field":
        import re

        return re.sub(r"(?<![\w.])-?\d+\.\d+", ".inf", good, count=3)
    if fmt == "transform":
        return "nan 0 0 0 0 inf\n"
    lines = good.splitlines()
    head, rows = lines[:1], lines[1:]
    cols = rows[0].split(",")
    k = 1 if fmt == "picks" else 0
    rows[0] = ",".join(c if i != k else "nan" for i, c in enumerate(cols))
    rows[1] = ",".join(c if i != k + 1 else "inf" for i, c in enumerate(rows[1].split(",")))
    return "\n".join(head + rows) + "\n"


def _header_variant(fmt: str) -> bytes:
    return {
        "bundle": b"schema_version: 99\ncameras: {}\n",
        "camera": b'{"unexpected": {"fields": 1}}\n',
        "transform": b"rotation: identity\n",
        "corners": b"a,b\n1,2\n3,4\n",
        "icorners": b"image;id;u;v\nfoo;bar\n",
        "uv": b"name,x\nfoo,1\n",
        "picks": b"x,y,z,u\n1,2,3,4\n",
        "field": b"outline: 12\n",
        "tracks": b'{"time": 1, "things": []}\n',
        "detections": b'{"when": 0, "what": 1}\n',
        "image": b"\x89PNG\r\n\x1a\n" + b"\x00" * 64,
        "cloud": b"# .PCD v0.7\nVERSION 0.7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n",
        "onnx": b"\x08\x07" + b"not a protobuf" * 4,
    }[fmt]


def _make_bad(kind: str, opt: Opt, world: dict, tmp: Path) -> Path | None:
    """The bad file for ``kind``, or None when the kind does not apply to this file."""
    good = world.get(opt.fmt)
    suffix = Path(good).suffix if isinstance(good, Path) else {"image": ".png", "text": ".txt"}.get(opt.fmt, ".dat")
    target = tmp / f"bad_{opt.fmt}{suffix}"
    if kind == "missing":
        return tmp / f"missing_{opt.fmt}{suffix}"
    if kind == "empty":
        target.write_bytes(b"")
    elif kind == "directory":
        target.mkdir()
    elif kind == "binary":
        target.write_bytes(bytes(range(256)) * 4)
    elif kind == "non-utf8":
        target.write_bytes(b"\xff\xfe\xfa name \x80\x81\x82\n1,2,3\n")
    elif kind == "nan":
        if opt.fmt not in GOOD_TEXT_FORMATS - {"names", "text"}:
            if opt.fmt == "cloud":
                target.write_text("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 200\nHEIGHT 1\nPOINTS 200\nDATA ascii\n" + "nan nan nan\n" * 200)
                return target
            return None
        target.write_text(_nan_variant(opt.fmt, Path(good).read_text()))
    elif kind == "header":
        if opt.fmt in ("names", "text"):
            return None
        target.write_bytes(_header_variant(opt.fmt))
    return target


def _readonly_dir(tmp: Path) -> Path:
    if os.geteuid() == 0:  # root writes through permission bits: /sys refuses new files even to root
        if not Path("/sys").is_dir():
            pytest.skip("running as root without /sys: no read-only folder to test with")
        return Path("/sys")
    d = tmp / "ro"
    d.mkdir()
    d.chmod(0o555)
    return d


def _cases():
    out = []
    for name, spec in TABLE.items():
        for o in spec.opts:
            kinds = {"input": INPUT_KINDS, "bundle": INPUT_KINDS + ("read-only",), "output": OUTPUT_KINDS,
                     "folder_in": FOLDER_IN_KINDS, "folder_out": FOLDER_OUT_KINDS}[o.role]
            for k in kinds:
                if k in o.skip or (o.role == "bundle" and k == "missing" and spec.creates_bundle):
                    continue
                out.append(pytest.param(name, o, k, id=f"{name}|{o.flag or o.fmt}|{k}"))
    return out


def _set(args: list, opt: Opt, value) -> list:
    args = list(args)
    if opt.flag is None:
        args[opt.index] = value
        return args
    spec = {"--bundle": ("-b", "--bundle"), "-o": ("-o", "--output", "--out"), "--points": ("--points",)}.get(opt.flag, (opt.flag,))
    for i, a in enumerate(args):
        if a in spec:
            args[i + 1] = value
            return args
    return [*args, opt.flag, value]


@pytest.mark.parametrize("name,opt,kind", _cases())
def test_bad_file(world, tmp_path, capsys, name, opt, kind):
    spec = TABLE[name]
    w = {**world, "tmp": tmp_path}
    bundle = tmp_path / "calib.yaml"
    shutil.copy(world["replay"] / "calib.yaml", bundle)
    bundle.chmod(0o640)
    w["bundle"] = bundle
    args = [str(a) for a in (opt.base or spec.base)(w)] + [str(a) for a in (opt.extra(w) if opt.extra else [])]
    culprit: Path
    if opt.role in ("input", "bundle"):
        if kind == "read-only":  # a bundle the command cannot write back
            if name in ("bundle show", "bundle validate", "report", "run", "bundle export"):
                pytest.skip("the command only reads the bundle")
            ro = _readonly_dir(tmp_path)
            if ro == Path("/sys"):
                pytest.skip("as root, a bundle in a read-only folder cannot be set up (nothing to read)")
            culprit = ro / "calib.yaml"
            ro.chmod(0o755)
            shutil.copy(world["replay"] / "calib.yaml", culprit)
            ro.chmod(0o555)
            bundle = culprit
        else:
            bad = _make_bad(kind, opt, w, tmp_path)
            if bad is None:
                pytest.skip(f"{kind} does not apply to a {opt.fmt} file")
            culprit = bad
            if opt.role == "bundle":
                bundle = bad
    elif opt.role == "output":
        culprit = {"no-folder": tmp_path / "nodir" / f"out{_ext(opt)}", "read-only": _readonly_dir(tmp_path) / f"radarcal-out{_ext(opt)}",
                   "is-folder": tmp_path / "afolder", "is-bundle": bundle}[kind]
        if kind == "is-folder":
            culprit.mkdir()
    elif opt.role == "folder_in":
        culprit = {"missing": tmp_path / "nofolder", "file": tmp_path / "a_file", "empty": tmp_path / "empty_folder"}[kind]
        if kind == "file":
            culprit.write_bytes(b"\x00\x01binary")
        elif kind == "empty":
            culprit.mkdir()
    else:  # folder_out
        culprit = {"is-file": tmp_path / "a_file", "read-only": _readonly_dir(tmp_path) / "radarcal-out"}[kind]
        if kind == "is-file":
            culprit.write_bytes(b"not a folder")
    args = _set(args, opt, str(culprit))
    before = _snapshot(bundle)
    try:
        code = main([_w for _w in name.split()] + args)
    finally:
        if culprit.parent.name == "ro":
            culprit.parent.chmod(0o755)
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert code == 2, f"exit {code}: {err[-800:]}"
    assert "Traceback" not in cap.err and "internal error" not in err, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    names = {str(culprit), culprit.name, opt.flag or "", str(culprit.parent)}
    assert any(n and n in lines[0] for n in names), f"the error does not name {culprit}: {err}"
    assert _snapshot(bundle) == before, "the bundle changed"


def _ext(opt: Opt) -> str:
    return {"image": ".png", "text": ".txt"}.get(opt.fmt, ".out")


def _snapshot(p: Path):
    if not p.is_file():
        return None
    return p.read_bytes(), stat.S_IMODE(p.stat().st_mode), sorted(x.name for x in p.parent.iterdir())
