"""radarcal: calibration for camera / LiDAR / mmWave-radar rigs.

Conventions (everywhere in the package):
- ``T_a_b`` is a 4x4 matrix mapping points in frame b into frame a: ``p_a = T_a_b @ p_b``.
- Camera frame: x right, y down, z forward (OpenCV). LiDAR: x forward, y left, z up.
- Metres and radians inside; degrees only at the user interface. Pixel centres at integer coordinates.
"""

__version__ = "0.1.0"

from radarcal.bundle import Bundle, load_bundle, save_bundle  # noqa: E402
from radarcal.camera import Camera  # noqa: E402

__all__ = ["__version__", "Bundle", "Camera", "load_bundle", "save_bundle"]
