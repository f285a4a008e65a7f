"""File readers and writers: images, point clouds, camera-intrinsics interop formats, 4x4 matrices.

Every reader validates at the boundary and raises :class:`radarcal.errors.InputError` naming the file.
"""

from radarcal.io.clouds import Cloud, read_cloud, write_pcd
from radarcal.io.images import read_image
from radarcal.io.camera_formats import export_camera, import_camera
from radarcal.io.matrices import read_transform

__all__ = ["Cloud", "read_cloud", "write_pcd", "read_image", "import_camera", "export_camera", "read_transform"]
