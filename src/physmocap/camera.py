"""Pinhole camera (OpenCV axes: x right, y down, z forward), its projection Jacobian, and the floor plane.

Extrinsics map world to camera: x_cam = R x_world + t. The world is Z up with the floor at z = 0 once the floor
is known; before that, a provisional world has the camera at the origin looking along +y with its x axis as x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

WORLD_UP = np.array([0.0, 0.0, 1.0])  # the world's up: the floor's normal once the floor is known (treat as read-only)
# Provisional world: camera at the origin, level, looking along +y (x_cam = x, y_cam = -z, z_cam = y).
PROVISIONAL_R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

DEFAULT_FOV_DEGREES = 60.0  # across the longer image side; typical of phones and webcams


@dataclass(frozen=True)
class Camera:
    """K (3, 3) intrinsics in pixels; R (3, 3), t (3,) world -> camera; image size (width, height)."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    image_size: tuple[int, int]

    @staticmethod
    def from_settings(image_size: tuple[int, int], focal: float | None = None, fov: float | None = None,
                      K: np.ndarray | None = None) -> Camera:
        """Intrinsics from an explicit K, a focal length (pixels) or a field of view (degrees across the
        longer image side); the principal point is the image centre. Default: DEFAULT_FOV_DEGREES."""
        w, h = image_size
        if K is None:
            if focal is None:
                fov = DEFAULT_FOV_DEGREES if fov is None else fov
                focal = 0.5 * max(w, h) / np.tan(np.radians(fov) / 2)
            K = np.array([[focal, 0.0, w / 2], [0.0, focal, h / 2], [0.0, 0.0, 1.0]])
        return Camera(np.asarray(K, float), PROVISIONAL_R.copy(), np.zeros(3), (int(w), int(h)))

    @property
    def focal(self) -> float:
        return float(0.5 * (self.K[0, 0] + self.K[1, 1]))

    @property
    def center(self) -> np.ndarray:
        """Camera position in the world."""
        return -self.R.T @ self.t

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world -> camera frame."""
        return points @ self.R.T + self.t

    def project(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 2) pixels."""
        return project_camera_points(self.K, self.to_camera(points))

    def projection_jacobian(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 2, 3) d pixels / d world position."""
        pc = self.to_camera(points)
        return projection_jacobian_camera(self.K, pc) @ self.R

    def with_extrinsics(self, R: np.ndarray, t: np.ndarray) -> Camera:
        return Camera(self.K, np.asarray(R, float), np.asarray(t, float), self.image_size)


def project_camera_points(K: np.ndarray, pc: np.ndarray) -> np.ndarray:
    """(..., 3) camera-frame points -> (..., 2) pixels."""
    z = np.maximum(pc[..., 2:3], 1e-6)
    uv = pc[..., :2] / z
    return uv @ K[:2, :2].T + K[:2, 2]


def projection_jacobian_camera(K: np.ndarray, pc: np.ndarray) -> np.ndarray:
    """(..., 3) camera-frame points -> (..., 2, 3) d pixels / d camera-frame position."""
    z = np.maximum(pc[..., 2], 1e-6)
    out = np.zeros(pc.shape[:-1] + (2, 3))
    out[..., 0, 0] = K[0, 0] / z
    out[..., 0, 1] = K[0, 1] / z
    out[..., 0, 2] = -(K[0, 0] * pc[..., 0] + K[0, 1] * pc[..., 1]) / z**2
    out[..., 1, 1] = K[1, 1] / z
    out[..., 1, 2] = -K[1, 1] * pc[..., 1] / z**2
    return out


@dataclass(frozen=True)
class Floor:
    """Plane n . x + d = 0 in the camera frame, n a unit vector pointing up (away from the ground), and how far
    it can be trusted: inlier_fraction, the share of the foot points it was fitted to within 10 cm of it;
    tilt_spread, degrees, the spread of its normal under a bootstrap of the foot points over seconds;
    prior_disagreement, degrees, between the plane of the feet alone and the person's own vertical (nan where
    not measured); trusted, False where they disagree so far that the normal is the person's vertical instead;
    source: "feet and posture", "feet" (fit_floor alone), "posture" or "unseen feet" (not trusted: the feet's plane
    leant from the posture, or no foot was in the picture), "contacts" (B.4's plane through the labelled contacts,
    refining a trusted one: tilt_spread and prior_disagreement are then the kinematic estimate's), or "given" (the
    user's)."""

    normal: np.ndarray
    offset: float
    inlier_fraction: float = 1.0
    tilt_spread: float = 0.0
    prior_disagreement: float = float("nan")
    trusted: bool = True
    source: str = "given"

    @property
    def plane(self) -> np.ndarray:
        return np.append(self.normal, self.offset)

    def confidence(self) -> dict:
        """The confidence fields for a result file: finite numbers, None where not measured."""
        def finite(x):
            return float(x) if np.isfinite(x) else None

        return dict(trusted=bool(self.trusted), source=self.source, inlier_fraction=finite(self.inlier_fraction),
                    tilt_spread_degrees=finite(self.tilt_spread),
                    prior_disagreement_degrees=finite(self.prior_disagreement))

    @staticmethod
    def from_plane(plane) -> Floor:
        plane = np.asarray(plane, float)
        norm = np.linalg.norm(plane[:3])
        return Floor(plane[:3] / norm, float(plane[3] / norm))

    def height(self, points_camera: np.ndarray) -> np.ndarray:
        return points_camera @ self.normal + self.offset


def tangent_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) orthogonal to the unit vector `up` and to each other."""
    a = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(a) < 0.1:
        a = np.cross(up, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    return a, np.cross(up, a)


class FloorResiduals:
    """The scaled residuals of `fit_floor` and their Jacobian in x = (tilt along a, tilt along b, offset): the
    normal is up + x0 a + x1 b normalised; one residual per point, its signed distance over huber_scale, and two
    prior residuals on the tilts."""

    def __init__(self, points: np.ndarray, up: np.ndarray, prior_weight: float, huber_scale: float):
        self.points, self.up, self.huber_scale = points, up, huber_scale
        self.a, self.b = tangent_basis(up)
        self.prior_scale = np.sqrt(prior_weight * len(points)) / huber_scale

    def normal(self, x: np.ndarray) -> np.ndarray:
        n = self.up + x[0] * self.a + x[1] * self.b
        return n / np.linalg.norm(n)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        dist = self.points @ self.normal(x) + x[2]
        return np.concatenate([dist / self.huber_scale, self.prior_scale * x[:2]])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """(N + 2, 3). The normal's derivative along a (b) is a's (b's) part orthogonal to it, over the length of
        up + x0 a + x1 b. Analytic: scipy's finite differences cost three more evaluations per step."""
        u = self.up + x[0] * self.a + x[1] * self.b
        length = np.linalg.norm(u)
        n = u / length
        tilts = np.stack([self.a - n * (n @ self.a), self.b - n * (n @ self.b)], axis=1) / length  # (3, 2)
        n_points = len(self.points)
        J = np.zeros((n_points + 2, 3))
        J[:n_points, :2] = self.points @ tilts / self.huber_scale
        J[:n_points, 2] = 1.0 / self.huber_scale
        J[n_points, 0] = J[n_points + 1, 1] = self.prior_scale
        return J


def fit_floor(points_camera: np.ndarray, up_prior: np.ndarray, prior_weight: float = 0.05,
              huber_scale: float = 0.02, outlier_distance: float = 0.10) -> tuple[Floor, np.ndarray]:
    """Robust (Huber) plane fit to foot points believed to touch the floor (Rempe et al. B.4).

    points_camera: (N, 3) candidate points; up_prior: (3,) rough up direction (e.g. the body's mean vertical
    axis), which also regularises the tilt when the points are clustered (a person standing still).
    prior_weight: strength of that regulariser relative to one point at 1 m; it is a plain quadratic, outside
    the robust loss (under Huber it would pull only linearly, and one wrongly labelled lifted foot far from the
    others could tilt the plane by 15 degrees). Returns the floor and a (N,) mask of inliers (points within
    `outlier_distance` of the plane).
    """
    up = up_prior / np.linalg.norm(up_prior)
    residuals = FloorResiduals(points_camera, up, prior_weight, huber_scale)
    n_points = len(points_camera)

    def huber_on_points(z):
        """least_squares' loss on squared residuals z (in units of huber_scale): Huber on the points,
        quadratic (identity) on the two prior residuals."""
        rho = np.stack([z, np.ones_like(z), np.zeros_like(z)])
        far = np.flatnonzero(z[:n_points] > 1.0)
        root = np.sqrt(z[far])
        rho[0, far], rho[1, far], rho[2, far] = 2 * root - 1, 1 / root, -0.5 / (z[far] * root)
        return rho

    d0 = -np.median(points_camera @ up)
    sol = least_squares(residuals, np.array([0.0, 0.0, d0]), jac=residuals.jacobian, loss=huber_on_points)
    n = residuals.normal(sol.x)
    dist = np.abs(points_camera @ n + sol.x[2])
    inliers = dist < outlier_distance
    return Floor(n, float(sol.x[2]), float(inliers.mean()), source="feet"), inliers


def angle_degrees(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two unit vectors (3,), degrees."""
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def robust_offset(points: np.ndarray, normal: np.ndarray, huber_scale: float = 0.02, iterations: int = 10) -> float:
    """The offset d of the plane normal . x + d = 0 through points (N, 3) for a fixed unit normal: Huber
    location of -points . normal, by iteratively reweighted means from the median."""
    values = -points @ normal
    d = float(np.median(values))
    for _ in range(iterations):
        weights = np.minimum(1.0, huber_scale / np.maximum(np.abs(values - d), 1e-12))
        d = float(np.sum(weights * values) / np.sum(weights))
    return d


def world_from_floor(floor: Floor, anchor_camera: np.ndarray, camera_x=(1.0, 0.0, 0.0)):
    """Extrinsics (R, t), world -> camera, of the world whose z = 0 plane is the floor, z up, origin on the
    floor below `anchor_camera` (camera-frame point, e.g. the first pelvis), x along the camera's x axis."""
    z = floor.normal
    camera_x = np.asarray(camera_x, float)
    x = camera_x - np.dot(camera_x, z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)  # columns: the world axes in camera coordinates
    origin = anchor_camera - floor.height(anchor_camera) * z
    return R, origin


def floor_in_camera(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4,) the world floor z = 0 as a plane n . x + d = 0 in camera coordinates, n a unit normal pointing up."""
    normal = R[:, 2]
    return np.append(normal, -normal @ t)
