"""The one calibration-target model of radarcal: a planar chessboard or ChArUco board and its corner coordinates.

Board frame (OpenCV's object-point convention): x along the columns, y along the rows, z into the board; metres.
Chessboard: ``cols x rows`` INNER corners, origin at the first inner corner, corner ``k = row * cols + col`` at
``(col * square, row * square, 0)`` (the order ``findChessboardCorners`` returns for an unrotated board).
ChArUco: ``cols x rows`` SQUARES, origin at the board's outer corner, corner ``id`` at
``((id % (cols-1) + 1) * square, (id // (cols-1) + 1) * square, 0)`` (= ``CharucoBoard.getChessboardCorners()``).

Used by detection/calibration (:mod:`radarcal.intrinsics`) and by the renderer (:mod:`radarcal.synth.board`).
Pure: no file I/O; OpenCV is imported only by :meth:`BoardSpec.cv_board` and the dictionary check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BoardSpec", "object_points", "BOARD_KINDS", "DEFAULT_DICTIONARY"]

BOARD_KINDS = ("chessboard", "charuco")
DEFAULT_DICTIONARY = "DICT_4X4_1000"


def _aruco():
    import cv2

    return cv2.aruco


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration target (validated on construction: ``ValueError`` with a one-line problem).

    kind: ``"chessboard"`` (``cols x rows`` = inner corners) or ``"charuco"`` (``cols x rows`` = squares).
    square / marker: metres (marker only for ChArUco). dictionary: OpenCV ArUco dictionary name.
    legacy: ChArUco layout, ``True`` = OpenCV's pre-4.6 layout (``setLegacyPattern(True)``), ``False`` = the new
    one, ``None`` = decide automatically (detection tries both; the renderer draws the new layout).
    margin: white paper beyond the outer squares (metres); ``None`` resolves to one square.
    """

    kind: str = "chessboard"
    cols: int = 9
    rows: int = 6
    square: float = 0.025
    marker: float | None = None
    dictionary: str = DEFAULT_DICTIONARY
    legacy: bool | None = None
    margin: float | None = None

    def __post_init__(self) -> None:
        problem = self.problem()
        if problem:
            raise ValueError(problem)
        if self.margin is None:  # resolve the default so that equal boards compare equal
            object.__setattr__(self, "margin", float(self.square))

    def problem(self) -> str | None:
        """One-line description of what is wrong with the spec, or None."""
        if self.kind not in BOARD_KINDS:
            return f"board: expected chessboard or charuco, got {self.kind!r}"
        if not (self.square > 0 and np.isfinite(self.square)):
            return f"square: must be positive, got {self.square}"
        if self.kind == "chessboard":
            if self.cols < 2 or self.rows < 2:
                return f"chessboard needs at least 2x2 inner corners, got {self.cols}x{self.rows}"
        else:
            if self.cols < 2 or self.rows < 2:
                return f"charuco needs at least 2x2 squares, got {self.cols}x{self.rows}"
            if self.marker is None or not (0 < self.marker < self.square):
                return f"marker: ChArUco marker size must be in (0, square={self.square}), got {self.marker}"
            if not (isinstance(self.dictionary, str) and self.dictionary.startswith("DICT_") and hasattr(_aruco(), self.dictionary)):
                return f"dictionary: unknown ArUco dictionary {self.dictionary!r}"
        if self.legacy not in (None, True, False):
            return f"legacy: expected true, false or null (automatic), got {self.legacy!r}"
        if self.margin is not None and not self.margin >= 0:
            return f"margin: must be >= 0, got {self.margin}"
        return None

    @property
    def squares_x(self) -> int:
        return self.cols + 1 if self.kind == "chessboard" else self.cols

    @property
    def squares_y(self) -> int:
        return self.rows + 1 if self.kind == "chessboard" else self.rows

    @property
    def corners_x(self) -> int:
        """Inner corners along x (columns of the corner grid)."""
        return self.squares_x - 1

    @property
    def corners_y(self) -> int:
        """Inner corners along y (rows of the corner grid)."""
        return self.squares_y - 1

    @property
    def n_corners(self) -> int:
        return self.corners_x * self.corners_y

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(corner rows, corner cols) of the inner-corner grid; corner ids are row-major in it."""
        return self.corners_y, self.corners_x

    @property
    def paper_margin(self) -> float:
        """White paper beyond the outer squares (metres)."""
        return self.square if self.margin is None else float(self.margin)

    @property
    def squares_extent(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the squares area in the board frame (metres)."""
        o = -self.square if self.kind == "chessboard" else 0.0
        return (o, o, o + self.squares_x * self.square, o + self.squares_y * self.square)

    @property
    def centre(self) -> np.ndarray:
        """Centre of the squares area in the board frame (3,), metres."""
        x0, y0, x1, y1 = self.squares_extent
        return np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])

    def to_dict(self) -> dict:
        """The ``board`` entry of a synth ``truth.json`` (radarcal-synth-board/1). ChArUco-only fields of a
        chessboard are written as ``marker: null, dictionary: null, legacy: false``."""
        charuco = self.kind == "charuco"
        return {
            "type": self.kind,
            "cols": self.cols,
            "rows": self.rows,
            "square": self.square,
            "marker": self.marker if charuco else None,
            "dictionary": self.dictionary if charuco else None,
            "legacy": self.legacy if charuco else False,
            "margin": self.paper_margin,
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "n_corners": self.n_corners,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "BoardSpec":
        """Inverse of :meth:`to_dict` (derived keys are ignored). Raises ``ValueError`` on a bad board."""
        charuco = d["type"] == "charuco"
        legacy = d.get("legacy") if charuco else None
        return cls(kind=d["type"], cols=int(d["cols"]), rows=int(d["rows"]), square=float(d["square"]),
                   marker=d.get("marker"), dictionary=d.get("dictionary") or DEFAULT_DICTIONARY,
                   legacy=None if legacy is None else bool(legacy), margin=d.get("margin"))

    def cv_board(self):
        """The ``cv2.aruco.CharucoBoard`` of a ChArUco spec (legacy flag applied, ``None`` as the new layout)."""
        if self.kind != "charuco":
            raise ValueError("cv_board: only for ChArUco boards")
        aruco = _aruco()
        dictionary = aruco.getPredefinedDictionary(getattr(aruco, self.dictionary))
        board = aruco.CharucoBoard((self.cols, self.rows), self.square, self.marker, dictionary)
        board.setLegacyPattern(bool(self.legacy))
        return board


def object_points(spec: BoardSpec) -> np.ndarray:
    """(N,3) inner-corner coordinates in the board frame (metres), indexed by corner id (row-major).

    Chessboard: origin at the first inner corner. ChArUco: origin at the board corner, identical to
    ``CharucoBoard.getChessboardCorners()``.
    """
    c, r = np.meshgrid(np.arange(spec.corners_x), np.arange(spec.corners_y))
    offset = 0.0 if spec.kind == "chessboard" else spec.square
    pts = np.zeros((spec.n_corners, 3))
    pts[:, 0] = c.ravel() * spec.square + offset
    pts[:, 1] = r.ravel() * spec.square + offset
    return pts
