"""Radar <-> radar, LiDAR <-> radar (trihedral corner reflectors) and LiDAR <-> LiDAR extrinsics of a vehicle rig.

Modules, along the jobs of the method (patent ``seeds/mining_lidar_radar_calibration_patent.txt`` and beyond it):

- :mod:`.geometry2d`: 2D rigid transforms of a level radar, the slant-range model, NLS fit with covariance, CR floor;
- :mod:`.matching`: mutual nearest neighbours, RANSAC over point pairs shared by several placements;
- :mod:`.reflectors`: ground plane, reflector extraction from a LiDAR cloud (head vs tripod, trihedral plate fit);
- :mod:`.detections`: radar frames averaged, RCS screening, the patent's A/B/C sets, the quantisation report;
- :mod:`.validation`: leave-one-out residuals, outlier rejection;
- :mod:`.rig`: every radar of a rig into the main LiDAR's frame (``calibrate_rig``);
- :mod:`.lidar_lidar`: other LiDARs registered to the main one (GICP + reflector point constraints, observability);
- :mod:`.session`: the typed session (inputs and results) and ``calibrate(...) -> RadarLidarResult`` the CLI calls.
"""

from radarcal.extrinsics.radar.detections import (
                                                  FilterResult,
                                                  aggregate_frames,
                                                  filter_detections,
                                                  frames_per_source,
                                                  quantisation_report,
)
from radarcal.extrinsics.radar.geometry2d import (
                                                  Fit2D,
                                                  Pose2,
                                                  deslant,
                                                  fit_rigid_2d,
                                                  multipath_of,
                                                  pose2_to_T,
                                                  procrustes_2d,
                                                  procrustes_floor,
                                                  rot2,
                                                  slant_predict,
                                                  wrap_angle,
)
from radarcal.extrinsics.radar.matching import (
                                                  mutual_nn,
                                                  robust_match_2d,
                                                  robust_match_sets,
)
from radarcal.extrinsics.radar.reflectors import (
                                                  GroundPlane,
                                                  ReflectorExtraction,
                                                  board_reflector_centres,
                                                  extract_reflectors,
                                                  fit_ground_plane,
)
from radarcal.extrinsics.radar.rig import (
                                                  RadarResult,
                                                  RigCalibration,
                                                  SceneObs,
                                                  build_scene_obs,
                                                  calibrate_rig,
)
from radarcal.extrinsics.radar.validation import leave_one_out, reject_outliers

__all__ = [
                                                  "FilterResult",
                                                  "Fit2D",
                                                  "GroundPlane",
                                                  "Pose2",
                                                  "RadarResult",
                                                  "ReflectorExtraction",
                                                  "RigCalibration",
                                                  "SceneObs",
                                                  "aggregate_frames",
                                                  "board_reflector_centres",
                                                  "build_scene_obs",
                                                  "calibrate_rig",
                                                  "deslant",
                                                  "extract_reflectors",
                                                  "filter_detections",
                                                  "fit_ground_plane",
                                                  "fit_rigid_2d",
                                                  "frames_per_source",
                                                  "leave_one_out",
                                                  "multipath_of",
                                                  "mutual_nn",
                                                  "pose2_to_T",
                                                  "procrustes_2d",
                                                  "procrustes_floor",
                                                  "quantisation_report",
                                                  "reject_outliers",
                                                  "robust_match_2d",
                                                  "robust_match_sets",
                                                  "rot2",
                                                  "slant_predict",
                                                  "wrap_angle",
]
