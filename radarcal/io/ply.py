"""The PLY header, parsed once for the cloud reader (:mod:`radarcal.io.clouds`) and the mesh reader
(:mod:`radarcal.io.meshes`): format, elements with their counts and properties, where the body starts."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radarcal.errors import InputError

__all__ = ["PLY_TYPES", "PlyElement", "PlyHeader", "read_ply_header"]

PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4", "double": "f8",
             "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}


@dataclass
class PlyElement:
    name: str
    count: int
    props: list[list[str]] = field(default_factory=list)  # "property" lines' tokens after the keyword: [type, name] or ["list", count type, index type, name]

    @property
    def is_list(self) -> bool:
        return any(p[0] == "list" for p in self.props)

    def dtype(self, byteorder: str) -> np.dtype:
        """The numpy record of one row (scalar properties only); ``InputError``-free: call after :meth:`unknown_types`."""
        return np.dtype([(p[-1], byteorder + PLY_TYPES[p[0]]) for p in self.props])

    def unknown_types(self) -> list[str]:
        return [t for p in self.props for t in (p[1:3] if p[0] == "list" else p[:1]) if t not in PLY_TYPES]


@dataclass
class PlyHeader:
    fmt: str | None  # "ascii" | "binary_little_endian" | "binary_big_endian" (anything else: not supported)
    elements: list[PlyElement]
    body_at: int  # byte offset of the body

    @property
    def byteorder(self) -> str:
        return ">" if self.fmt == "binary_big_endian" else "<"

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


def read_ply_header(data: bytes, path: Path, not_ply: str = "not a PLY file (no 'ply' magic / end_header)") -> PlyHeader:
    """Parse the header of the PLY bytes ``data`` (``InputError(path, not_ply)`` without the magic or ``end_header``)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(path, not_ply)
    nl = data.find(b"\n", end)
    fmt, elements = None, []
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format" and len(tok) > 1:
            fmt = tok[1]
        elif tok[0] == "element":
            try:
                elements.append(PlyElement(tok[1], int(tok[2])))
            except (IndexError, ValueError):
                raise InputError(path, f"PLY bad element line {line!r}") from None
        elif tok[0] == "property" and elements and len(tok) >= 3:
            elements[-1].props.append(tok[1:])
    return PlyHeader(fmt, elements, len(data) if nl < 0 else nl + 1)
