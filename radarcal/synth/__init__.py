"""Ground-truth scene generators (data in users' formats + ``truth.json``)."""

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
