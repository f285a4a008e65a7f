"""Ground-truth scene generators (`radarcal synth <scene>`): data in users' formats plus ``truth.json``.

Import scene modules directly (`radarcal.synth.field`, `radarcal.synth.radar`, ...); the board names are re-exported here."""

from radarcal.synth.board import (
    BoardRenderer,
    BoardSpec,
    RenderSettings,
    board_object_points,
    board_truth_pixels,
    default_camera,
    render_board,
    load_board_truth,
    write_board_set,
)

__all__ = [
    "BoardRenderer",
    "BoardSpec",
    "RenderSettings",
    "board_object_points",
    "board_truth_pixels",
    "default_camera",
    "render_board",
    "load_board_truth",
    "write_board_set",
]
