"""Calibration-target images with known truth (``radarcal synth board``), split along its jobs:
:mod:`radarcal.synth.board_render` (the inverse-mapping renderer), :mod:`radarcal.synth.board_views` (camera presets,
view plans, video trajectories), :mod:`radarcal.synth.board_set` (the set writer and its truth reader). The names are
re-exported here; board geometry is :mod:`radarcal.board` (``board_object_points`` is ``object_points``)."""

from radarcal.board import BoardSpec, object_points
from radarcal.synth.board_render import BoardRenderer, RenderSettings, bad_view_amplitude, board_truth_pixels, bow_warp, render_blank, render_board
from radarcal.synth.board_set import TRUTH_FORMAT, BoardTruth, load_board_truth, write_board_set
from radarcal.synth.board_views import BoardView, default_camera, default_stereo_camera, model_name, plan_views, video_trajectory

board_object_points = object_points  # the same function, under the name this module has always exported

__all__ = [
    "BoardSpec",
    "RenderSettings",
    "BoardRenderer",
    "BoardView",
    "board_object_points",
    "default_camera",
    "default_stereo_camera",
    "model_name",
    "bow_warp",
    "bad_view_amplitude",
    "plan_views",
    "render_board",
    "render_blank",
    "board_truth_pixels",
    "write_board_set",
    "video_trajectory",
    "load_board_truth",
    "BoardTruth",
    "TRUTH_FORMAT",
]
