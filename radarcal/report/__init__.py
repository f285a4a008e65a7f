"""Figures shared by ``radarcal report`` and the notebooks.

Every figure function takes numpy arrays (and :class:`radarcal.camera.Camera` objects) and returns a matplotlib
``Figure`` built without pyplot (Agg canvas; no file reading). :mod:`radarcal.report.html` assembles figures into one
self-contained HTML page; :mod:`radarcal.report.build` turns a bundle's session files into report sections.
"""

from radarcal.report._common import figure_to_png, show
from radarcal.report.field import (
    camera_position_on_field,
    error_over_time_figure,
    field_landmarks_figure,
    localisation_error_figure,
    minimap_tracks_figure,
    picks_residual_figure,
)
from radarcal.report.html import Section, Table, render_html
from radarcal.report.radar import (
    detection_category,
    radar_points_in_main,
    radar_sigma_figure,
    radar_top_view_figure,
    rcs_range_figure,
    reflector_residuals_figure,
)
from radarcal.teams import team_of, track_colours
from radarcal.report.intrinsics import (
    coverage_figure,
    coverage_grid,
    crossval_difference_figure,
    distortion_displacement,
    distortion_figure,
    parameter_table_figure,
    per_view_error_figure,
    projection_difference,
    residual_histogram_figure,
    residual_vectors_figure,
    uncertainty_map_figure,
    valid_region,
)
from radarcal.report.lidar_camera import (
    cloud_overlay_figure,
    cost_profile_figure,
    cost_profiles,
    edge_matches_figure,
    edge_residual_histogram_figure,
    project_cloud,
)

__all__ = [
    "figure_to_png",
    "show",
    "Section",
    "Table",
    "render_html",
    # intrinsics
    "per_view_error_figure",
    "residual_vectors_figure",
    "residual_histogram_figure",
    "coverage_grid",
    "coverage_figure",
    "valid_region",
    "uncertainty_map_figure",
    "distortion_displacement",
    "distortion_figure",
    "projection_difference",
    "crossval_difference_figure",
    "parameter_table_figure",
    # lidar-camera
    "project_cloud",
    "cloud_overlay_figure",
    "edge_matches_figure",
    "edge_residual_histogram_figure",
    "cost_profiles",
    "cost_profile_figure",
    # field / run
    "camera_position_on_field",
    "field_landmarks_figure",
    "picks_residual_figure",
    "localisation_error_figure",
    "minimap_tracks_figure",
    "error_over_time_figure",
    "track_colours",
    "team_of",
    # radar-lidar
    "detection_category",
    "radar_points_in_main",
    "reflector_residuals_figure",
    "radar_top_view_figure",
    "rcs_range_figure",
    "radar_sigma_figure",
]
