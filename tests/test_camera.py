import numpy as np

from physmocap.camera import Camera, Floor, FloorResiduals, fit_floor, world_from_floor


def test_projection_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    cam = Camera.from_settings((640, 480), focal=500.0)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    cam = cam.with_extrinsics(R, np.array([0.1, -0.2, 5.0]))
    pts = rng.normal(size=(7, 3))
    J = cam.projection_jacobian(pts)
    eps = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        assert np.allclose((cam.project(pts + d) - cam.project(pts - d)) / (2 * eps), J[..., k], atol=1e-6)


def test_floor_residuals_jacobian_matches_finite_differences():
    rng = np.random.default_rng(4)
    up = np.array([0.1, -0.95, -0.3])
    residuals = FloorResiduals(rng.normal([0.0, 1.5, 4.0], 1.0, (9, 3)), up / np.linalg.norm(up), 0.05, 0.02)
    x = np.array([0.07, -0.04, 1.3])
    J = residuals.jacobian(x)
    eps = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        assert np.allclose((residuals(x + d) - residuals(x - d)) / (2 * eps), J[:, k], atol=1e-5)


def test_intrinsics_from_field_of_view_and_default():
    cam = Camera.from_settings((1000, 500), fov=90.0)
    assert np.isclose(cam.focal, 500.0) and np.allclose(cam.K[:2, 2], [500, 250])
    default = Camera.from_settings((1000, 500))
    assert np.isclose(default.focal, 500.0 / np.tan(np.radians(30)))  # 60 degrees across the width


def test_robust_floor_fit_ignores_outliers_and_world_puts_floor_at_zero():
    rng = np.random.default_rng(1)
    normal = np.array([0.0, -np.cos(0.2), -np.sin(0.2)])  # camera pitched down by 0.2 rad
    offset = 1.4
    base = rng.uniform([-1.0, 0, 3.0], [1.0, 0, 6.0], size=(300, 3))
    # project onto the plane
    on_plane = base - (base @ normal + offset)[:, None] * normal
    noisy = on_plane + rng.normal(scale=0.005, size=on_plane.shape)
    outliers = on_plane[:30] + 0.3 * normal  # feet labelled in contact while lifted
    pts = np.vstack([noisy, outliers])
    floor, inliers = fit_floor(pts, up_prior=np.array([0.0, -1.0, 0.0]))
    # The up prior is 11.5 degrees off and pulls quadratically: a small tilt, the plane within 3 cm at the feet.
    assert np.degrees(np.arccos(np.clip(floor.normal @ normal, -1, 1))) < 1.0
    assert np.abs(floor.height(on_plane)).max() < 0.03
    assert inliers[:300].mean() > 0.98 and not inliers[300:].any()
    R, t = world_from_floor(floor, on_plane[0] + 0.9 * normal)
    world = (pts[:300] - t) @ R  # camera -> world
    assert np.abs(world[:, 2]).max() < 0.05
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(Floor.from_plane(2 * floor.plane).plane, floor.plane)


def test_floor_tilt_prior_is_not_overruled_by_one_outlier():
    """A person standing still touches the floor along a line, so the tilt about that line rests on the prior;
    one lifted foot wrongly labelled in contact, 1 m aside and 0.3 m up, must not tilt the plane (with the
    prior inside the Huber loss it pulled only linearly and the plane tilted by 16 degrees)."""
    rng = np.random.default_rng(2)
    up = np.array([0.0, -np.cos(0.2), -np.sin(0.2)])
    offset = 1.4
    across = np.cross(up, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    along = np.cross(up, across)
    centre = np.array([0.0, 0.0, 4.0])
    centre -= (centre @ up + offset) * up  # on the floor
    feet = centre + rng.uniform(-0.12, 0.12, (8, 1)) * along + rng.normal(scale=0.003, size=(8, 3))
    lifted = centre + 1.0 * across + 0.3 * up
    floor, inliers = fit_floor(np.vstack([feet, lifted]), up_prior=up)
    assert np.degrees(np.arccos(np.clip(floor.normal @ up, -1, 1))) < 5.0
    assert abs(floor.height(centre)) < 0.01
    assert inliers[:8].all() and not inliers[8]
