"""The take-off interval's path onto the flight's parabola (dynamics/ballistic.py) and the tracker that follows it."""

import numpy as np
import pytest

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.config import PhysicsSettings
from physmocap.dynamics.ballistic import flight_velocity, take_off_paths
from physmocap.dynamics.stage import run_physcap

G = 9.81


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.75), 72.0)


def take_off_heights(fps: float, take_off: float = 0.88, push: float = 12.0, flight: float = 0.5,
                     seconds: float = 1.6) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A centre of mass at rest at 0.9 m, pushed up at a constant `push` m/s^2 for 0.2 s until `take_off` s, then
    ballistic for `flight` s and at rest again: heights (T,) m at `fps`, contact flags (T, 4), and the true take-off
    velocity (m/s) and share of its frame interval at which it leaves."""
    t = np.arange(int(round(seconds * fps)) + 1) / fps
    start, v0 = take_off - 0.2, push * 0.2
    lift = 0.9 + 0.5 * push * 0.2 ** 2
    s = np.clip(t - start, 0.0, 0.2)
    z = 0.9 + 0.5 * push * s * s
    air = (t > take_off) & (t < take_off + flight)
    z[air] = lift + v0 * (t[air] - take_off) - 0.5 * G * (t[air] - take_off) ** 2
    z[t >= take_off + flight] = lift + v0 * flight - 0.5 * G * flight ** 2
    return z, np.repeat(~air[:, None], 4, axis=1), v0, take_off * fps % 1.0


def test_a_take_off_path_meets_the_flights_parabola_in_height_and_velocity():
    heights, contacts, v0, share = take_off_heights(10.0)
    paths = take_off_paths(heights, contacts, np.ones(len(heights), bool), 10.0, G)
    first = int(np.flatnonzero(~contacts.any(axis=1))[0])
    assert list(paths) == [first]
    path = paths[first]
    # the flight's parabola is fitted exactly from ballistic frames: the take-off velocity, back from the first frame
    assert path.flight_velocity == pytest.approx(v0 - G * (1.0 - share) / 10.0, abs=1e-9)
    # through both frames, and continuous in height and velocity where the contacts let go
    assert path.offsets(0.0)[0] == pytest.approx(0.0, abs=1e-12)
    assert path.offsets(1.0)[0] == pytest.approx(0.0, abs=1e-12)
    before, after = path.offsets(path.switch - 1e-9), path.offsets(path.switch + 1e-9)
    assert after[0] == pytest.approx(before[0], abs=1e-8) and after[1] == pytest.approx(before[1], abs=1e-6)
    assert after[2] == -G and before[2] > -G  # a push on the floor side, gravity alone on the flight's
    # it leaves near the true instant (the contact frame's velocity is a centred difference, not the truth's)
    assert path.switch == pytest.approx(share, abs=0.15)


def test_flights_too_short_that_do_not_rise_need_too_large_a_push_or_are_not_finite_get_no_take_off_path():
    heights, contacts, _, _ = take_off_heights(10.0)
    first = int(np.flatnonzero(~contacts.any(axis=1))[0])
    one_frame = contacts.copy()
    one_frame[first + 1:] = True
    assert take_off_paths(heights, one_frame, np.ones(len(heights), bool), 10.0, G) == {}
    standing = np.full(len(heights), 0.9)  # labels with a flight in which the body stays where it stood
    assert take_off_paths(standing, contacts, np.ones(len(heights), bool), 10.0, G) == {}
    unusable = np.ones(len(heights), bool)
    unusable[first - 2] = False  # the contact frame's velocity needs the frame before it
    assert take_off_paths(heights, contacts, unusable, 10.0, G) == {}
    # the 12 m/s^2 push (2.2 body weights) is beyond a bound of 1.5 body weights
    assert take_off_paths(heights, contacts, np.ones(len(heights), bool), 10.0, G, max_force=1.5) == {}
    broken = heights.copy()
    broken[first + 1] = np.nan  # a non-finite target (the tracker restarts there): no path from it
    assert take_off_paths(broken, contacts, np.ones(len(heights), bool), 10.0, G) == {}


def test_the_flight_velocity_is_the_least_squares_parabola_through_the_first_frame():
    s = np.arange(5) * 0.1
    heights = 1.0 + 2.0 * s - 0.5 * G * s * s + np.array([0.0, 0.01, -0.01, 0.01, -0.01])
    noisy = flight_velocity(heights, 0.1, G)
    assert noisy == pytest.approx(2.0, abs=0.05)
    assert flight_velocity(heights[:2], 0.1, G) == pytest.approx(2.0 + 0.1, abs=1e-9)  # through both frames


def crouched(body, knee: np.ndarray) -> np.ndarray:
    """Poses (T, nq) with the knees bent by `knee` (T,) rad and the hips and ankles by half as much the other way,
    the feet flat on the floor."""
    step = np.zeros((len(knee), body.nv))
    for side in ("left", "right"):
        step[:, body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = -knee
        step[:, body.dof_address[body.joint_index[f"{side}_knee"]]] = 2 * knee
        step[:, body.dof_address[body.joint_index[f"{side}_ankle"]] + 1] = -knee
    q = kin.integrate(body, np.repeat(body.rest_qpos[None], len(knee), axis=0), step)
    q[:, 2] -= kin.forward_kinematics(body, q).points[:, body.point_index(CONTACT_POINTS), 2].min(axis=1)
    return q


def squat_jump(body, fps: float, take_off: float = 0.88, push: float = 0.25, peak: float = 25.0,
               seconds: float = 1.8) -> tuple[np.ndarray, np.ndarray]:
    """A squat jump: from a crouch, the legs extend with the feet flat while the root's upward acceleration falls
    steadily from `peak` m/s^2 to -g (the floor's push fading out) over `push` s until `take_off` s; then the body
    flies ballistically in its take-off posture. Poses (T, nq) and contact flags (T, 4)."""
    knee = np.linspace(0.2, 1.4, 400)
    root = crouched(body, knee)[:, 2]  # falling as the knees bend
    t = np.arange(int(round(seconds * fps)) + 1) / fps
    u = np.clip(t - (take_off - push), 0.0, push)
    rise = peak * u * u / 2 - (peak + G) * u ** 3 / (6 * push)
    v0 = (peak - G) * push / 2
    q = crouched(body, np.interp(root[0] - rise[-1] + rise, root[::-1], knee[::-1]))
    s = t - take_off
    air = (s > 0) & (v0 * s - 0.5 * G * s * s > 0)
    q[air, 2] = root[0] + v0 * s[air] - 0.5 * G * s[air] ** 2
    return q, np.repeat(~air[:, None], 4, axis=1)


def test_at_10_fps_a_jump_leaves_the_floor_fast_enough_to_reach_its_apex(body):
    """The take-off falls late in a 10 fps frame interval, whose chord rises far slower than the jump: aiming at
    it, the character's apex was 6 cm low; pushed onto the flight's parabola, it is within 2 cm."""
    q, contacts = squat_jump(body, 10.0)
    truth, _ = squat_jump(body, 600.0)
    apex = kin.center_of_mass(body, kin.forward_kinematics(body, truth))[:, 2].max()
    motion = run_physcap(body, q, 10.0, contacts, np.zeros(len(q), bool), PhysicsSettings(), refined_input=True)
    reached = kin.center_of_mass(body, kin.forward_kinematics(body, motion.qpos))[:, 2].max()
    assert not motion.unexplained.any()
    assert abs(reached - apex) < 0.02
