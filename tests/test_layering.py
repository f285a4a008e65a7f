"""The house rule of issue #13: file formats are decoded (and encoded) only in ``radarcal/io/``; nothing in
``radarcal/runtime/`` reads or writes a file format itself, it calls an ``io`` reader or writer.

Read by ``ast`` (no import of the modules): a runtime module may not import a format library (json, yaml, csv, struct,
...) nor call ``open()``, ``Path.read_text`` / ``read_bytes`` / ``write_text`` / ``write_bytes``, the image and video
codecs of OpenCV (``imread``, ``imdecode``, ``imwrite``, ``imencode``, ``VideoCapture``, ``VideoWriter``), numpy's file
readers and writers (``np.load``, ``np.fromfile``, ``np.save`` ...) or ``onnx.load`` / ``onnx.save``. An inference
engine handed a model path (``onnxruntime.InferenceSession``, OpenVINO ``compile_model``) is execution, not a decoder
radarcal writes, and is not counted. The few exceptions are listed in :data:`ALLOWED`, each with its reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

RUNTIME = Path(__file__).resolve().parents[1] / "radarcal" / "runtime"  # the checkout this test lives in

FORMAT_MODULES = {"json", "yaml", "ruamel", "csv", "struct", "zipfile", "tarfile", "gzip", "bz2", "lzma", "pickle", "shelve", "sqlite3",
                  "configparser", "tomllib", "tomli", "ast", "xml", "h5py", "PIL", "imageio", "pandas", "rosbags", "open3d", "plyfile",
                  "laspy", "pypcd"}  # fmt: skip
FILE_CALLS = {"open", "read_text", "read_bytes", "write_text", "write_bytes", "fromfile", "tofile", "loadtxt", "genfromtxt", "savetxt",
              "imread", "imreadmulti", "imdecode", "imwrite", "imencode", "VideoCapture", "VideoWriter", "VideoWriter_fourcc"}  # fmt: skip
MODULE_FILE_CALLS = {"np": {"load", "save", "savez", "savez_compressed", "memmap"}, "numpy": {"load", "save", "savez", "savez_compressed", "memmap"},
                     "onnx": {"load", "load_model", "save", "save_model"}}  # fmt: skip

# (module path under runtime/, import or call): why it is not a file format
ALLOWED = {
    ("referee.py", "struct"): "the referee serial protocol (frames of a device link, packed and parsed here by design), not a file",
    ("console/server.py", "json"): "bodies of the console's HTTP API (a web wire format between radarcal and the browser), not a file",
    ("console/server.py", "read_bytes"): "the console's static page assets, served as they are (never decoded)",
    ("console/live.py", "json"): "the console's server-sent events to the browser (HTTP), not a file",
    ("console/live.py", "imencode"): "the console's camera view: a JPEG body of an HTTP response for the browser, not a file",
}


def _root(name: str | None) -> str:
    return (name or "").split(".")[0]


def _called(func: ast.expr) -> tuple[str | None, str] | None:
    """(base name or None, called name) of a call's function: ``open`` -> (None, "open"), ``cv2.imdecode`` -> ("cv2", "imdecode")."""
    if isinstance(func, ast.Name):
        return None, func.id
    if isinstance(func, ast.Attribute):
        base = func.value
        return (base.id if isinstance(base, ast.Name) else None), func.attr
    return None


def file_format_uses(source: str) -> list[tuple[int, str]]:
    """(line, what) for every format-library import and file-reading or -writing call in a module's source."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, _root(a.name)) for a in node.names if _root(a.name) in FORMAT_MODULES]
        elif isinstance(node, ast.ImportFrom) and not node.level and _root(node.module) in FORMAT_MODULES:
            found.append((node.lineno, _root(node.module)))
        elif isinstance(node, ast.Call) and (called := _called(node.func)) is not None:
            base, name = called
            if name in FILE_CALLS or name in MODULE_FILE_CALLS.get(base or "", ()):
                found.append((node.lineno, name))
    return found


def _runtime_modules() -> list[Path]:
    return sorted(RUNTIME.rglob("*.py"))


def test_the_checker_finds_what_it_forbids():
    src = ("import json\nfrom yaml import safe_load\nimport cv2\nimport numpy as np\nfrom pathlib import Path\n"
           "f = open('x')\nimg = cv2.imdecode(b, 1)\ncap = cv2.VideoCapture('v.mp4')\na = np.load('a.npy')\n"
           "t = Path('p').read_text()\nb = np.fromfile('b')\nok = cv2.imwrite('m.png', img)\n")  # fmt: skip
    assert file_format_uses(src) == [(1, "json"), (2, "yaml"), (6, "open"), (7, "imdecode"), (8, "VideoCapture"), (9, "load"), (10, "read_text"),
                                     (11, "fromfile"), (12, "imwrite")]  # fmt: skip
    assert file_format_uses("import numpy as np\nx = np.asarray([1])\nfrom radarcal.io.images import read_image\nread_image('a.png')\n") == []


def test_no_runtime_module_decodes_a_file_format():
    modules = _runtime_modules()
    assert len(modules) >= 20, f"runtime modules not found under {RUNTIME}"
    bad, used = [], set()
    for path in modules:
        rel = path.relative_to(RUNTIME).as_posix()
        for line, what in file_format_uses(path.read_text(encoding="utf-8")):
            if (rel, what) in ALLOWED:
                used.add((rel, what))
            else:
                bad.append(f"radarcal/runtime/{rel}:{line}: {what}")
    assert not bad, "file formats are decoded in radarcal/io/, not in runtime/ (move the reader or writer there):\n" + "\n".join(bad)
    stale = sorted(set(ALLOWED) - used)
    assert not stale, f"allow-list entries no longer needed (remove them): {stale}"
