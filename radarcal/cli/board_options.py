"""The board flags, declared once for every command that takes a calibration target (``intrinsics``, ``synth board``).

Defaults are :class:`radarcal.board.BoardSpec`'s (9x6 chessboard, 25 mm squares, ``DICT_4X4_1000``); a ChArUco board
without ``--marker`` gets markers of 0.75 x the square. Use as ``board: BoardKindOpt = BOARD.kind``, ... and build the
spec with :func:`board_spec`.
"""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Optional

import typer

from radarcal.board import BoardSpec
from radarcal.errors import InputError

__all__ = ["BoardKind", "BoardLayout", "BOARD", "BoardKindOpt", "ColsOpt", "RowsOpt", "SquareOpt", "MarkerOpt", "DictOpt", "LayoutOpt", "board_spec"]

BOARD = BoardSpec()  # the defaults of every board flag


class BoardKind(str, Enum):
    chessboard = "chessboard"
    charuco = "charuco"


class BoardLayout(str, Enum):
    """ChArUco layout: ``auto`` (detection tries both; the renderer draws the new one), ``new`` (OpenCV >= 4.6), ``legacy``."""

    auto = "auto"
    new = "new"
    legacy = "legacy"


BoardKindOpt = Annotated[BoardKind, typer.Option("--board", help="Calibration target.")]
ColsOpt = Annotated[int, typer.Option("--cols", help="Chessboard: inner corners per row (along x). ChArUco: squares per row.")]
RowsOpt = Annotated[int, typer.Option("--rows", help="Chessboard: inner corners per column (along y). ChArUco: squares per column.")]
SquareOpt = Annotated[float, typer.Option("--square", help="Square size (m).")]
MarkerOpt = Annotated[Optional[float], typer.Option("--marker", help="ChArUco marker size (m; default 0.75 x --square).")]
DictOpt = Annotated[str, typer.Option("--dict", help="ChArUco ArUco dictionary (OpenCV name).")]
LayoutOpt = Annotated[BoardLayout, typer.Option("--layout", help="ChArUco layout: auto (detect both; render the new one), new (OpenCV >= 4.6) or legacy (pre-4.6).")]


def board_spec(kind: BoardKind, cols: int, rows: int, square: float, marker: float | None, dictionary: str, layout: BoardLayout) -> BoardSpec:
    """The :class:`BoardSpec` of the board flags (``InputError("--board", ...)`` naming what is wrong)."""
    charuco = kind == BoardKind.charuco
    if charuco and marker is None:
        marker = 0.75 * square
    legacy = {BoardLayout.auto: None, BoardLayout.new: False, BoardLayout.legacy: True}[layout]
    try:
        return BoardSpec(kind.value, cols, rows, square, marker if charuco else None, dictionary, legacy if charuco else None)
    except ValueError as e:
        raise InputError("--board", str(e)) from None
