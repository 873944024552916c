"""The video's clock against gravity (kinematics.clock): jumps fall at g on a right clock; slow motion, a wrong
stated rate, standing bodies the labels call airborne and supported descents."""

import numpy as np
import pytest

from physmocap.kinematics.clock import CLOCK_TOLERANCE, airborne, check_clock, flight_arcs
from physmocap.metrics import GRAVITY


def jumps(true_fps: float, seconds: float = 6.0, flight: float = 0.5, every: float = 2.0, noise: float = 0.005,
          seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames at true_fps of a body standing at 1 m that jumps every `every` s for `flight` s: the centre of mass
    height (T,), sole heights (T, 4) and contact labels (T, 4), with `noise` m of height noise. The labels keep
    the frame before the arc and the frame after it in contact, the centre of mass on the arc's ends there (the
    crouch the push leaves, the catch)."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * true_fps)) / true_fps
    phase = np.mod(t, every) - (every - flight) / 2  # each flight in the middle of its period
    up = (phase > 0) & (phase < flight)
    arc = np.abs(phase - flight / 2) < flight / 2 + 1.0 / true_fps
    com = 1.0 + np.where(arc, GRAVITY / 2 * phase * (flight - phase), 0.0) + noise * rng.standard_normal(len(t))
    soles = np.repeat(np.where(up, com - 1.0, 0.0)[:, None], 4, axis=1)
    return com, soles, np.repeat(~up[:, None], 4, axis=1)


def test_jumps_on_a_right_clock_fall_at_g():
    com, soles, contacts = jumps(30.0)
    check = check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0, "clip.mp4")
    assert check.arcs == 3 and check.warning == ""
    assert check.fall == pytest.approx(GRAVITY, rel=0.1)
    assert check.consistent_fps == pytest.approx(30.0, rel=0.05)


def test_footage_filmed_at_25_fps_stated_as_10_is_found_and_its_rate_named():
    """Issue 17's parkour files: every jump falls at g (10 / 25)^2 on the stated clock."""
    com, soles, contacts = jumps(25.0)
    check = check_clock(com, soles, contacts, np.ones(len(com), bool), 10.0, "vault.mp4")
    assert check.fall == pytest.approx(GRAVITY * (10 / 25) ** 2, rel=0.1)
    assert check.consistent_fps == pytest.approx(25.0, rel=0.05)
    assert check.warning.startswith(f"vault.mp4: its jumps fall at {check.fall:.1f} m/s^2, not 9.8")
    assert "slower than it was filmed" in check.warning
    assert check.warning.endswith(f"give --fps {check.consistent_fps:.0f}.")


def test_a_file_stating_too_many_frames_per_second_is_found_too():
    com, soles, contacts = jumps(30.0)
    check = check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0 * CLOCK_TOLERANCE, "x.mp4")
    assert "faster than it was filmed" in check.warning and check.consistent_fps == pytest.approx(30.0, rel=0.05)


def test_a_jump_whose_top_the_labels_call_a_contact_still_counts():
    """A slowed video's labels can call the top of a jump a contact: every sole point high above the floor is
    airborne whatever the labels say."""
    com, soles, contacts = jumps(30.0)
    high = soles.min(axis=1) > 0.3
    contacts[high] = True
    assert airborne(soles, contacts)[high].all()
    assert check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0, "x").arcs == 3


def test_a_standing_body_labelled_airborne_and_a_supported_descent_are_no_arcs():
    fps, rng = 30.0, np.random.default_rng(1)
    standing = 1.0 + 0.005 * rng.standard_normal(90)
    descent = 1.5 - 0.5 * np.linspace(0, 1, 90) ** 2 / 2  # lowered from a wall by the hands: no top, slow
    for com in (standing, descent):
        assert flight_arcs(com, np.ones(90, bool), np.ones(90, bool), fps) == []
        check = check_clock(com, np.full((90, 4), 0.3), np.zeros((90, 4), bool), np.ones(90, bool), fps, "x")
        assert check.arcs == 0 and np.isnan(check.fall) and check.warning == ""


def test_a_non_finite_height_is_no_arc_and_no_error():
    com, soles, contacts = jumps(30.0, seconds=2.0)
    com[np.flatnonzero(~contacts.any(axis=1))[3]] = np.nan
    assert check_clock(com, soles, contacts, np.ones(len(com), bool), 30.0, "x").arcs == 0


def test_frames_without_a_person_split_a_flight():
    """A flight is judged within a run of valid frames: no parabola through a gap the fit filled in."""
    com, soles, contacts = jumps(30.0, seconds=2.0)
    air = airborne(soles, contacts)
    middle = np.flatnonzero(air)[len(np.flatnonzero(air)) // 2]
    valid = np.ones(len(com), bool)
    valid[middle] = False
    arcs = flight_arcs(com, air, valid, 30.0)
    assert all(arc.stop <= middle or arc.start > middle for arc in arcs)


@pytest.mark.parametrize("hold", [0.0, 0.5, 1.0])
def test_a_pull_up_is_no_flight_however_slow(hold):
    """Feet off the floor, the body pulled up 0.5 m in 1 s, held, lowered in 1 s: it rises and falls, but its path
    is no parabola, and taken for one it would read as slow motion (falls of 0.5-1.1 m/s^2)."""
    fps = 30.0
    ramp = 0.25 * (1 - np.cos(np.pi * np.arange(30) / 30))
    path = np.concatenate([np.zeros(10), ramp, np.full(int(hold * fps), 0.5), ramp[::-1], np.zeros(10)])
    soles = np.where(path[:, None] > 0, 0.3, 0.0).repeat(4, axis=1)
    contacts = soles < 0.1
    check = check_clock(1.0 + path, soles, contacts, np.ones(len(path), bool), fps, "bar.mp4")
    assert check.arcs == 0 and check.warning == ""
