"""Reading a Qualisys (QTM) camera calibration export, `.qca.txt`: XML with one <camera> element per camera.

What the file holds and how it becomes OpenCV cameras (x right, y down, z forward; x_cam = R x_world + t):

- <transform x y z r11 .. r33>: the camera centre in the world, millimetres, and a rotation matrix M whose rows
  are the camera's axes in world coordinates for a camera frame with x right, y UP and z pointing BACKWARDS out of
  the lens. So M maps world to that frame, and the OpenCV rotation is R = diag(1, -1, -1) M, t = -R centre.
- <intrinsic>: focal lengths and principal point in sensor sub-pixels, 64 per pixel (sensorMaxU is 64 times
  the last pixel column), of the whole sensor.
- <fov_video left top right bottom>: the sensor pixels (inclusive) that the video frames show; the principal
  point is shifted by its top-left corner and the frame size is its extent.
- radial/tangential distortion: read as OpenCV's (k1, k2, p1, p2, k3) of normalised image coordinates.

Verified on the Pose2Sim demo calibration (four portrait 1088x1920 Miqus views): with these conventions the world
origin, projected into every view, lands on the same physical corner of the force plate within a few pixels, and
the cameras look at a common point with positive depth. The distortion convention could not be confirmed there:
the lenses are mild (about 6 px at the frame corners) and the person stays near the image centre, where reading
the coefficients as OpenCV's, scaled by 1/64 or ignoring them changes triangulation by less than 0.05 px.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from physmocap.camera import Camera

SUBPIXELS_PER_PIXEL = 64.0
"""QTM states intrinsics in sensor sub-pixels, 64 to a pixel."""

QUALISYS_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
"""Rotation from the Qualisys camera frame (x right, y up, z backwards) to OpenCV's (x right, y down, z forward)."""


@dataclass(frozen=True)
class QualisysCamera:
    """One calibrated camera, in OpenCV conventions and metres.

    name: the camera's serial (e.g. "cam01"). K: (3, 3) intrinsics in pixels of the video frame.
    distortion: (5,) OpenCV coefficients k1, k2, p1, p2, k3. R: (3, 3), t: (3,) metres, world -> camera.
    image_size: (width, height) of the calibrated video frame, pixels. residual: QTM's average residual (as
    exported; millimetres in QTM).
    """

    name: str
    K: np.ndarray
    distortion: np.ndarray
    R: np.ndarray
    t: np.ndarray
    image_size: tuple[int, int]
    residual: float

    @property
    def centre(self) -> np.ndarray:
        """(3,) camera position in the world, metres."""
        return -self.R.T @ self.t

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) unit viewing direction (camera +z) in world coordinates."""
        return self.R[2].copy()

    @property
    def focal(self) -> float:
        """Mean focal length, pixels."""
        return float(0.5 * (self.K[0, 0] + self.K[1, 1]))

    def camera(self) -> Camera:
        """The pinhole `Camera` (lens distortion left out)."""
        return Camera(self.K.copy(), self.R.copy(), self.t.copy(), self.image_size)


def _number(element: ElementTree.Element, name: str) -> float:
    value = element.get(name)
    if value is None:
        raise ValueError(f"Qualisys calibration: <{element.tag}> lacks the attribute {name!r}")
    try:
        return float(value)
    except ValueError:
        raise ValueError(f"Qualisys calibration: <{element.tag} {name}={value!r}> is not a number") from None


def _child(camera: ElementTree.Element, tag: str) -> ElementTree.Element:
    element = camera.find(tag)
    if element is None:
        raise ValueError(f"Qualisys calibration: camera {camera.get('serial')!r} has no <{tag}>")
    return element


def _parse_camera(element: ElementTree.Element) -> QualisysCamera:
    name = element.get("serial") or ""
    rotation = element.get("viewrotation", "0")
    if rotation not in ("0", ""):
        raise ValueError(f"Qualisys calibration: camera {name!r} has viewrotation={rotation}; only unrotated "
                         "views are supported")
    resolution = element.get("video_resolution")
    if resolution not in (None, "1080p"):
        raise ValueError(f"Qualisys calibration: camera {name!r} records video at {resolution}; only full "
                         "sensor resolution is supported")

    transform = _child(element, "transform")
    qualisys_rotation = np.array([[_number(transform, f"r{row}{col}") for col in (1, 2, 3)] for row in (1, 2, 3)])
    if not np.allclose(qualisys_rotation @ qualisys_rotation.T, np.eye(3), atol=1e-6) \
            or np.linalg.det(qualisys_rotation) < 0:
        raise ValueError(f"Qualisys calibration: camera {name!r} has a transform that is not a rotation")
    centre = np.array([_number(transform, axis) for axis in ("x", "y", "z")]) / 1000.0
    R = QUALISYS_TO_OPENCV @ qualisys_rotation
    t = -R @ centre

    fov = _child(element, "fov_video")
    left, top = _number(fov, "left"), _number(fov, "top")
    width = int(round(_number(fov, "right") - left + 1))
    height = int(round(_number(fov, "bottom") - top + 1))

    intrinsic = _child(element, "intrinsic")
    K = np.array([
        [_number(intrinsic, "focalLengthU") / SUBPIXELS_PER_PIXEL, 0.0,
         _number(intrinsic, "centerPointU") / SUBPIXELS_PER_PIXEL - left],
        [0.0, _number(intrinsic, "focalLengthV") / SUBPIXELS_PER_PIXEL,
         _number(intrinsic, "centerPointV") / SUBPIXELS_PER_PIXEL - top],
        [0.0, 0.0, 1.0],
    ])
    K[0, 1] = float(intrinsic.get("skew", 0.0)) / SUBPIXELS_PER_PIXEL  # taken to be in sub-pixels like the focals
    distortion = np.array([float(intrinsic.get(key, 0.0)) for key in (
        "radialDistortion1", "radialDistortion2", "tangentalDistortion1", "tangentalDistortion2",
        "radialDistortion3")])
    return QualisysCamera(name, K, distortion, R, t, (width, height), float(element.get("avg-residual", "nan")))


def parse_qualisys_calibration(xml_text: str) -> list[QualisysCamera]:
    """The active cameras of a Qualisys calibration given as XML text, in file order."""
    try:
        root = ElementTree.fromstring(xml_text)
    except ElementTree.ParseError as exc:
        raise ValueError(f"Qualisys calibration: not valid XML ({exc})") from None
    cameras = [_parse_camera(element) for element in root.iter("camera") if element.get("active", "1") != "0"]
    if not cameras:
        raise ValueError("Qualisys calibration: no active <camera> element")
    return cameras


def read_qualisys_calibration(path: str | os.PathLike) -> list[QualisysCamera]:
    """The active cameras of a `.qca.txt` file, in file order."""
    return parse_qualisys_calibration(Path(path).read_text(encoding="utf-8", errors="replace"))
