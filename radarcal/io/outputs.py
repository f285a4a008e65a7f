"""Output files the user names (``-o``, ``--out``, ``--overlay``, ``--error-map``, ...), checked before a command
changes anything: an output is never the bundle (or one of its session files, or its backups), its folder exists
and is writable, and it is not a folder. A command calls :func:`check_outputs` once, before its first save, so a
command that fails on an output has changed nothing.

:func:`input_file` is the same idea for inputs: a file the user names exists, is a file and is readable, checked
where it enters (``error: <file>: <problem>``, exit 2).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
import contextlib
import fnmatch
import shutil
from typing import Iterable, Iterator

from radarcal.errors import InputError

__all__ = ["check_outputs", "check_output", "protected_paths", "input_file", "replace_folder"]


def _resolve(p: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.expanduser(os.fspath(p))))


def protected_paths(bundle_path: str | os.PathLike | None, bundle=None) -> dict[Path, str]:
    """Files no output may overwrite: the bundle, its session files (folder ``<stem>.sessions``) and backups.
    Returns {resolved path: what it is}."""
    out: dict[Path, str] = {}
    if bundle_path is None:
        return out
    bp = _resolve(bundle_path)
    out[bp] = "the bundle"
    sessions = bp.parent / f"{bp.stem}.sessions"
    out[sessions] = "the bundle's session folder"
    if sessions.is_dir():
        for f in sessions.iterdir():
            out[_resolve(f)] = "a session file of the bundle"
    if bundle is not None:
        for rel in getattr(bundle, "sessions", {}).values():
            out[_resolve(bp.parent / rel)] = "a session file of the bundle"
    for bak in bp.parent.glob(f"{bp.name}.*.bak") if bp.parent.is_dir() else ():
        out[_resolve(bak)] = "a backup of the bundle"
    return out


def _same_file(a: Path, b: Path) -> bool:
    if a == b:
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _writable_folder(folder: Path) -> str | None:
    """None when a file can be created in ``folder``, else why not (tries it: permission bits lie for root)."""
    if not folder.exists():
        return f"folder {folder} does not exist"
    if not folder.is_dir():
        return f"{folder} is not a folder"
    try:
        fd, tmp = tempfile.mkstemp(prefix=".radarcal-write-test.", dir=folder)
    except OSError as e:
        return f"folder {folder} is not writable ({e.strerror or e.__class__.__name__})"
    os.close(fd)
    try:
        os.unlink(tmp)
    except OSError:
        pass
    return None


def check_output(path: str | os.PathLike, protected: dict[Path, str] | None = None, what: str = "output file", folder: bool = False) -> Path:
    """Raise :class:`InputError` naming ``path`` unless it can be written without harm. ``folder``: the output is
    a folder (created by the command; its parent must be writable, an existing one must be a folder)."""
    p = Path(path)
    rp = _resolve(p)
    for q, name in (protected or {}).items():
        if _same_file(rp, q) or (folder and (q == rp or rp in q.parents)):
            raise InputError(p, f"the {what} would overwrite {name}; give another file name")
    if folder:
        if rp.exists() and not rp.is_dir():
            raise InputError(p, "exists and is not a folder")
        why = _writable_folder(rp if rp.exists() else rp.parent)
        if why:
            raise InputError(p, f"cannot write the {what}: {why}")
        return p
    if rp.is_dir():
        raise InputError(p, f"is a folder; give a file name for the {what}")
    why = _writable_folder(rp.parent)
    if why:
        raise InputError(p, f"cannot write the {what}: {why}")
    if rp.exists():
        try:
            with open(rp, "ab"):
                pass
        except OSError as e:
            raise InputError(p, f"cannot write the {what} ({e.strerror or e.__class__.__name__})") from None
    return p


def check_outputs(bundle_path: str | os.PathLike | None, outputs: Iterable[tuple[str, str | os.PathLike | None]], bundle=None,
                  inputs: Iterable[str | os.PathLike | None] = ()) -> None:
    """Check every ``(what, path)`` output (``None`` paths skipped) against the bundle and its files and the
    command's ``inputs``, and that it is writable; two outputs may not be the same file either."""
    prot = protected_paths(bundle_path, bundle)
    for i in inputs:
        if i is not None and _resolve(i) not in prot:
            prot[_resolve(i)] = f"the input {i}"
    seen: dict[Path, str] = {}
    for what, path in outputs:
        if path is None:
            continue
        check_output(path, {**prot, **seen}, what)
        seen[_resolve(path)] = f"the {what}"


def input_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a readable file, or :class:`InputError`: ``<what> not found`` / ``is a folder`` / ``cannot read``."""
    p = Path(path)
    if not p.exists():
        raise InputError(p, f"{what} not found")
    if p.is_dir():
        raise InputError(p, f"is a folder, expected a {what}")
    try:
        with open(p, "rb"):
            pass
    except OSError as e:
        raise InputError(p, f"cannot read the {what} ({e.strerror or e.__class__.__name__})") from None
    return p


@contextlib.contextmanager
def replace_folder(out: str | os.PathLike, overwrite: bool, allowed: Iterable[str] = (), what: str = "output") -> Iterator[Path]:
    """Write a generated folder atomically: yields a fresh temporary folder next to ``out``; when the block ends
    without an exception it becomes ``out`` (an earlier ``out`` is replaced only with ``overwrite`` and only when
    every entry in it matches one of the ``allowed`` glob patterns); on an error or Ctrl-C it is removed and
    ``out`` is untouched. A non-empty ``out`` without ``overwrite`` is refused before anything is written."""
    out = Path(out)
    if out.exists():
        if not out.is_dir():
            raise InputError(out, "exists and is not a folder")
        entries = sorted(p.name for p in out.iterdir())
        if entries and not overwrite:
            raise InputError(out, f"folder is not empty ({len(entries)} entries, e.g. {entries[0]}: an earlier run?); give a new folder or --overwrite to replace it")
        foreign = [e for e in entries if not any(fnmatch.fnmatch(e, pat) for pat in allowed)]
        if foreign:
            raise InputError(out, f"holds files that are not a {what}'s ({', '.join(foreign[:3])}); not replaced, give a new folder")
    check_output(out, what=what, folder=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent if str(out.parent) else "."))
    try:
        from radarcal.bundle import _umask

        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it 0700; a folder the user creates follows the umask
        yield tmp
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
