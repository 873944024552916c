"""The video's clock against gravity (kinematics.clock): jumps fall at g on a right clock; slow motion, a wrong
stated rate, standing bodies the labels call airborne and supported descents."""

import numpy as np
import pytest

from physmocap.kinematics.clock import CLOCK_TOLERANCE, airborne, check_clock, flight_arcs
from physmocap.metrics import GRAVITY

CLEARANCE = 0.1  # m, physics' contact_height


def jumps(true_fps: float, seconds: float = 6.0, flight: float = 0.5, every: float = 2.0, noise: float = 0.005,
          seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames at true_fps of a body standing at 1 m that jumps every `every` s for `flight` s: the centre of mass
    height (T,), sole heights (T, 4) and contact labels (T, 4), with `noise` m of height noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * true_fps)) / true_fps
    phase = np.mod(t, every) - (every - flight) / 2  # each flight in the middle of its period
    up = (phase > 0) & (phase < flight)
    lift = np.where(up, GRAVITY / 2 * phase * (flight - phase), 0.0)
    com = 1.0 + lift + noise * rng.standard_normal(len(t))
    soles = np.repeat(lift[:, None], 4, axis=1)
    return com, soles, np.repeat(~up[:, None], 4, axis=1)


def test_jumps_on_a_right_clock_fall_at_g():
    com, soles, contacts = jumps(30.0)
    check = check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0, CLEARANCE, "clip.mp4")
    assert check.arcs == 3 and check.warning == ""
    assert check.fall == pytest.approx(GRAVITY, rel=0.1)
    assert check.consistent_fps == pytest.approx(30.0, rel=0.05)


def test_footage_filmed_at_25_fps_stated_as_10_is_found_and_its_rate_named():
    """Issue 17's parkour files: every jump falls at g (10 / 25)^2 on the stated clock."""
    com, soles, contacts = jumps(25.0)
    check = check_clock(com, soles, contacts, np.ones(len(com), bool), 10.0, CLEARANCE, "vault.mp4")
    # the parabola runs through the take-off and landing frames, where the body still pushes: a little flatter
    assert check.fall == pytest.approx(GRAVITY * (10 / 25) ** 2, rel=0.15)
    assert check.consistent_fps == pytest.approx(25.0, rel=0.08)
    assert check.warning.startswith(f"vault.mp4: its jumps fall at {check.fall:.1f} m/s^2, not 9.8")
    assert "slower than it was filmed" in check.warning
    assert check.warning.endswith(f"give --fps {check.consistent_fps:.0f}.")


def test_a_file_stating_too_many_frames_per_second_is_found_too():
    com, soles, contacts = jumps(30.0)
    check = check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0 * CLOCK_TOLERANCE, CLEARANCE, "x.mp4")
    assert "faster than it was filmed" in check.warning and check.consistent_fps == pytest.approx(30.0, rel=0.05)


def test_a_jump_whose_top_the_labels_call_a_contact_still_counts():
    """A slowed video's labels can call the top of a jump a contact: every sole point high above the floor is
    airborne whatever the labels say."""
    com, soles, contacts = jumps(30.0)
    high = soles.min(axis=1) > 0.3
    contacts[high] = True
    assert airborne(soles, contacts, CLEARANCE)[high].all()
    assert check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0, CLEARANCE, "x").arcs == 3


def test_a_standing_body_labelled_airborne_and_a_supported_descent_are_no_arcs():
    fps, rng = 30.0, np.random.default_rng(1)
    standing = 1.0 + 0.005 * rng.standard_normal(90)
    descent = 1.5 - 0.5 * np.linspace(0, 1, 90) ** 2 / 2  # lowered from a wall by the hands: no top, slow
    for com in (standing, descent):
        assert flight_arcs(com, np.ones(90, bool), np.ones(90, bool), fps) == []
        check = check_clock(com, np.full((90, 4), 0.3), np.zeros((90, 4), bool), np.ones(90, bool), fps,
                            CLEARANCE, "x")
        assert check.arcs == 0 and np.isnan(check.fall) and check.warning == ""


def test_frames_without_a_person_split_a_flight():
    """A flight is judged within a run of valid frames: no parabola through a gap the fit filled in."""
    com, soles, contacts = jumps(30.0, seconds=2.0)
    air = airborne(soles, contacts, CLEARANCE)
    middle = np.flatnonzero(air)[len(np.flatnonzero(air)) // 2]
    valid = np.ones(len(com), bool)
    valid[middle] = False
    arcs = flight_arcs(com, air, valid, 30.0)
    assert all(arc.stop <= middle or arc.start > middle for arc in arcs)
