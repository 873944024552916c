"""Typed settings, one dataclass per stage, each field declared once by `setting(default, unit, limits, meaning)`:
check(), the command line's help and docs/settings.md (scripts/settings_reference.py) come from it. Defaults are
the papers' values where they give one; the measurements behind the others are in docs/decisions/. A TOML file
(`--config`) overrides them with the same section and field names, e.g. `[fit]` then `weight_depth = 0.5`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .errors import SettingsError
from .settings_fields import Section, floor_plane, image_box, load_toml, setting


@dataclass(frozen=True)
class BodySettings(Section):
    height: float = setting(1.70, "m", (1.0, 2.3), "the person's standing height")
    mass: float = setting(70.0, "kg", (20.0, 250.0), "the person's mass")
    calibration_frames: int = setting(0, "frames", (0, 100000), "bone lengths from the first ones; 0: all (online 3 s)")
    estimate_height: bool = setting(False, help="height from the detector's 3D landmarks as metres (height: fallback)")


@dataclass(frozen=True)
class CameraSettings(Section):
    focal: float | None = setting(None, "px", (1.0, 1e6), "focal length; overrides fov")
    fov: float | None = setting(None, "deg", (10.0, 160.0), "field of view across the longer image side (None: 60)")
    floor: tuple[float, float, float, float] | None = setting(None, "m", check=floor_plane, help="plane n.x + d = 0 "
                                                              "in the camera frame (None: estimated from the feet)")
    fps: float | None = setting(None, "fps", (1.0, 1000.0), "the camera's frames per second, where the file plays them "
                                "at another rate (slow motion) (None: the file's)")


@dataclass(frozen=True)
class DetectSettings(Section):
    max_width: int | None = setting(None, "px", (160, 4096), "search regions downscaled to this (None: native)")
    person_box: tuple[float, float, float, float] | None = setting(None, "px", help="x0,y0,x1,y1: the person to "
                                                                   "follow", check=image_box)
    accept_truncated: bool = setting(False, help="capture the decodable part of a truncated video, not stop")
    graphs: int | None = setting(None, "", (1, 2), "MediaPipe graphs detecting halves of a video of 300 frames or "
                                 "more at once (None: 2 where the process has 2 cores, not in a batch worker)")


@dataclass(frozen=True)
class FitSettings(Section):
    """Kinematic fit, PhysCap eq. (3). Residuals are in metres (2D errors scaled to the person's depth), so the
    weights compare directly; temporal terms are stated at 30 fps. Tuning: docs/decisions/fit-settings.md."""

    weight_2d: float = setting(1.0, "", (0.0, 1000.0), "E_proj: reprojection")
    weight_3d: float = setting(0.3, "", (0.0, 1000.0), "E_IK: root-relative 3D landmarks")
    weight_smooth: float = setting(0.1, "", (0.0, 1000.0), "E_smooth: acceleration of the joints")
    weight_depth: float = setting(0.03, "", (0.0, 1000.0), "E_depth: change of the joints' depth along the view")
    weight_prior: float = setting(1e-4, "", (0.0, 1000.0), "pull of ball joints to a neutral pose: resolves twists")
    weight_limits: float = setting(10.0, "", (0.0, 1000.0), "hinge joint limits")
    limit_band: float = setting(0.2, "rad", (0.0, 1.0), "rounds the limits' kink off so the fit sees them coming")
    hand_weight: float = setting(0.25, "", (0.0, 1.0), "on the hand's own markers: noisy, they pulled the elbows")
    min_confidence: float = setting(0.1, "", (0.0, 1.0), "keypoints below this confidence are ignored")
    robust_2d: float = setting(0.05, "m", (0.0, 1.0), "reprojection errors beyond this count linearly; 0: off")
    robust_3d: float = setting(0.10, "m", (0.0, 1.0), "weighted 3D landmark errors beyond this count linearly; 0: off")
    offline_iterations: int = setting(8, "", (1, 200), "Levenberg-Marquardt iterations over the whole clip")
    online_iterations: int = setting(4, "", (1, 50), "Levenberg-Marquardt iterations per frame when causal, at "
                                    "30 fps (lower rates: as many per second)")
    offline_start_iterations: int = setting(2, "", (1, 50), "the same for the causal fits the offline fit starts from")
    undo_foot_swaps: bool = setting(True, help="fit back feet the detector swapped left for right")
    rescale_landmark_depth: bool = setting(True, help="offline: undo the detector's per-frame depth stretch")
    refine_lengths: bool = setting(True, help="measure the limbs and feet again along a first fit's axes, refit")
    offline_chunk: int = setting(32, "frames", (2, 100000), "length of the causal runs the offline fit starts from")
    one_euro: bool = setting(False, help="One-Euro filter on the fitted pose (Casiez et al. 2012)")
    one_euro_min_cutoff: float = setting(1.5, "Hz", (0.01, 30.0), "the One-Euro filter's minimum cutoff")
    one_euro_beta: float = setting(0.3, "", (0.0, 10.0), "the One-Euro filter's speed coefficient")
    weight_contact_velocity: float = setting(0.0, "", (0.0, 1000.0), "Rempe's E_cont (B6): feet moving in contact (10)")
    weight_floor: float = setting(0.0, "", (0.0, 1000.0), "Rempe's E_floor (B7), heel/toe in contact; ours: dips (10)")
    weight_velocity: float = setting(0.0, "", (0.0, 1000.0), "Rempe's E_vel (B2): joint velocity (paper 0.1)")
    weight_angle_velocity: float = setting(0.0, "", (0.0, 1000.0), "Rempe's E_ang (B3): joint angle change (0.1)")
    angle_speed_huber: float = setting(2.0, "rad/s", (0.0, 100.0), "E_ang pulls linearly on joints faster (0: off)")
    angle_speed_huber_frames: str = setting("running", choices=("running", "all"), help="frames where it does: "
                                            "where the body runs (faster than the walk-run transition), or all")
    weight_com_acceleration: float = setting(0.0, "", (0.0, 1000.0), "acceleration of the centre of mass (ours)")


@dataclass(frozen=True)
class PhysicsSettings(Section):
    """Physics after the kinematic fit: PhysCap stage III (Shimada et al. 2020, 4.3 and 5.1) for "physcap".
    Tuning: docs/decisions/physcap-tracking.md, physcap-contacts.md and physcap-online-floor.md."""

    method: str = setting("physcap", choices=("physcap", "trajopt", "none"), help="PhysCap's tracker per frame, "
                          "Rempe's trajectory optimisation of the whole clip (offline only), or none")
    refine_offline: bool = setting(True, help="offline, PhysCap tracks the B.4 refinement, not the plain fit")
    stray_distance: float = setting(0.15, "m", (0.01, 10.0), "frames straying farther from the kinematics are "
                                    "reported; online, a person seen again farther off restarts the character")
    kp_joint: float = setting(1200.0, "1/s^2", (0.0, 1e4), "joint stiffness; the paper's 300 lagged the motion")
    kd_joint: float = setting(70.0, "1/s", (0.0, 1e4), "joint damping (paper 20; both critically damped)")
    kp_joint_refined: float | None = setting(2000.0, "1/s^2", (0.0, 1e4), "joint stiffness offline, on B.4's "
                                             "smooth whole-clip refinement, which kp_joint lags (None: kp_joint)")
    kd_joint_refined: float | None = setting(89.4, "1/s", (0.0, 1e4), "its damping (None: kd_joint)")
    kp_root_rotation: float = setting(1200.0, "1/s^2", (0.0, 1e4), "stiffness of the root's orientation (paper 340)")
    kd_root_rotation: float = setting(70.0, "1/s", (0.0, 1e4), "damping of the root's orientation (paper 30)")
    kp_root_translation: float = setting(1000.0, "1/s^2", (0.0, 1e4), "stiffness of the root's position")
    kd_root_translation: float = setting(80.0, "1/s", (0.0, 1e4), "damping of the root's position")
    kp_root_horizontal: float | None = setting(250.0, "1/s^2", (0.0, 1e4), "horizontal stiffness (ours; None: above)")
    kd_root_horizontal: float | None = setting(32.0, "1/s", (0.0, 1e4), "its damping (None: kd_root_translation)")
    acceleration_feedforward: float = setting(1.0, "", (0.0, 1.0), "eq. (4) feed-forward times x/(e^x-1), x = kd/fps")
    velocity_smoothing: float = setting(0.03, "s", (0.0, 1.0), "smoothing of eq. (4)'s kinematic velocity (B.4 input: "
                                        "both ways, no lag); 0: none")
    rotation_velocity_share: float = setting(0.8, "", (0.0, 1.0), "of the rotational velocity eq. (4) tracks (paper 1)")
    contact_height: float = setting(0.1, "m", (0.0, 1.0), "psi of eq. (5): predicted contacts count only below it")
    target_lift_time: float | None = setting(0.1, "s", (0.001, 10.0), "time constant lifting a target whose "
                                             "contacts sink under the floor, which held the body (None: off)")
    flatten_feet: bool = setting(True, help="with the lift, a target foot in contact at heel and toe turns flat")
    friction: float = setting(0.8, "", (0.05, 2.0), "mu; the pyramid uses mu / sqrt(2) (eq. 7)")
    slide_speed: float = setting(0.3, "m/s", (0.0, 1.0), "sigma of eq. (9): slip a contact keeps (lower locks feet)")
    step: float | None = setting(None, "s", (1e-4, 0.1), "phi of eq. (1) (None: one frame / iterations)")
    iterations: int = setting(4, "", (1, 50), "n, steps ii-v per frame")
    torque_weight: float = setting(4.5e-4, "", (0.0, 1.0), "of |tau|^2 against |qdd - qdd_des|^2 (authors' code)")
    residual_weight: float = setting(3e-3, "", (0.0, 1e3), "the same for the root's actuation (4.5e-4 starved it)")
    residual_weight_vertical: float = setting(1e-2, "", (0.0, 1e3), "its vertical force: weight belongs on the feet")
    foot_lock: str = setting("auto", choices=("auto", "always", "never"), help="contacts: predicted; any sole point "
                             "within contact_height; none and no floor (airborne)")
    penetration_recovery: float = setting(0.1, "s", (1e-3, 1.0), "a point under the floor rises back at depth / this")
    contact_settle_time: float = setting(0.05, "s", (1e-3, 1.0), "a held point above its target drops at height / this")
    release_distance: float | None = setting(0.05, "m", (0.0, 1.0), "freed past this slide of its target (None: never)")
    plant_time: float | None = setting(0.1, "s", (0.01, 10.0), "fits not refined by B.4 (online): a held target foot "
                                       "follows the fit's with this time constant, within release_distance (None: off)")
    plant_reach: float | None = setting(0.02, "m", (0.0, 1.0), "the output's held contact points stand on one spot "
                                        "(offline the middle of the contact's path, online where it began), "
                                        "which follows them only past this distance (0 or None: off)")
    rest_height: float | None = setting(0.02, "m", (0.0, 0.5), "online: a target sole point under this height, "
                                        "slower than slide_speed, is in contact (None: off)")
    touch_margin: float = setting(0.003, "m", (0.0, 0.1), "sole points this close collide with the floor (eq. 5)")
    floor_clearance: float = setting(0.0005, "m", (0.0, 0.01), "physics floor this far up: turning feet dip under it")
    floor_refit_interval: float | None = setting(3.0, "s", (0.1, 60.0), "between online refits of the floor to the "
                                                 "contact points (None: the warm-up's is kept)")
    floor_refine_after: float = setting(3.0, "s", (0.0, 60.0), "of frames before the first refit")
    floor_tilt_rate: float = setting(1.0, "deg/s", (0.01, 90.0), "the fastest the refined floor turns")
    floor_lift_rate: float = setting(0.05, "m/s", (0.001, 1.0), "the fastest the refined floor moves along its normal")
    balance_correction: bool = setting(True, help="4.3.1: straighten stationary poses leaning off their support")
    correction_time: float = setting(0.316, "s", (0.01, 10.0), "time constant of that correction (the paper's "
                                     "theta / 10 per frame at 30 fps)")
    stationary_max_speed: float | None = setting(0.25, "m/s", (0.01, 10.0), "the stationary flag is believed only "
                                                 "while the root is slower (None: always)")
    stationary_speed_interval: float = setting(0.2, "s", (0.01, 2.0), "over which that speed is measured")
    step_stability_share: float | None = setting(0.5, "", (0.05, 0.95), "longest step as a share of the PD's "
                                                 "stability limit (None: iterations; physics-frame-rate.md)")
    max_force: float = setting(10.0, "body weights", (1.0, 100.0), "larger contact/residual forces are cut and flagged")
    unexplained_force: float | None = setting(0.5, "body weights", (0.05, 10.0), "upward root force no floor "
                                              "contact gives that flags a frame (None: not checked)")
    unexplained_time: float = setting(0.2, "s", (0.01, 2.0), "averaging time of that force and of the needed support")
    unexplained_blend: float = setting(0.2, "s", (0.0, 2.0), "output passes to the kinematic motion and back over it "
                                       "(online and live, from the first flagged frame on)")
    unexplained_blend_offline: float = setting(0.4, "s", (0.0, 2.0), "the same with the whole clip, on either side "
                                               "of each flagged stretch (physics-limits.md)")
    start_drop_time: float | None = setting(0.5, "s", (0.01, 10.0), "a target starting with its feet above the floor "
                                            "(under contact_height) is lowered onto it, fading so (None: off)")


TRAJOPT_CONSTRAINTS: tuple[str, ...] = ("dynamics", "acceleration_continuity", "velocity_boundaries", "foot_length",
                                         "leg_length", "force_limits", "above_floor")
TRAJOPT_COSTS: tuple[str, ...] = ("data", "velocity", "acceleration", "duration", "force_rate")


@dataclass(frozen=True)
class TrajoptSettings(Section):
    """Trajectory optimisation of the whole clip, Rempe et al. 2020 (3.1, figure 3, appendices B and C): the
    paper's values where it gives one, "ours" the others (docs/decisions/trajopt-settings.md)."""

    kinematic_contact_velocity: float = setting(10.0, "", (0.0, 1000.0), "alpha_cont of the B.4 fit")
    kinematic_floor: float = setting(10.0, "", (0.0, 1000.0), "alpha_floor of the B.4 fit")
    kinematic_velocity: float = setting(0.1, "", (0.0, 1000.0), "alpha_vel of the B.4 fit")
    kinematic_angle_velocity: float = setting(0.1, "", (0.0, 1000.0), "alpha_ang of the B.4 fit")
    kinematic_com_acceleration: float = setting(100.0, "", (0.0, 1000.0), "the B.4 fit's weight_com_acceleration")
    floor_outlier_distance: float = setting(0.05, "m", (0.01, 1.0), "contacts farther from the floor: dropped (ours)")
    floor_pitch_prior: float = setting(0.05, "", (0.0, 10.0), "per contact at 1 m, against the B.4 floor tilting "
                                       "to the camera, as depth errors tilt it (ours)")
    floor_roll_prior: float = setting(0.002, "", (0.0, 10.0), "the same about the view axis, which the image fixes")
    contact_slip_speed: float = setting(1.2, "m/s", (0.0, 100.0), "contacts sliding faster are dropped (ours); 0: off")
    contact_slip_interval: float = setting(0.1, "s", (0.01, 1.0), "over which that and rest_speed are measured")
    rest_height: float = setting(0.02, "m", (0.0, 0.5), "below this and slower than rest_speed: contact (ours); 0: off")
    rest_speed: float = setting(0.6, "m/s", (0.0, 10.0), "Rempe's label speed (3.2)")
    com_interval: float = setting(0.05, "s", (0.02, 1.0), "between COM polynomial knots (C.1; paper 0.1)")
    segments_per_phase: int = setting(6, "", (1, 50), "least polynomials per force phase, flight (each >= a frame)")
    segment_phase_seconds: float = setting(2.0, "s", (0.1, 60.0), "longer phases get proportionally more")
    min_phase_seconds: float = setting(0.06, "s", (0.0, 1.0), "shorter contact flag runs join neighbours (ours)")
    contact_drift: float = setting(0.05, "m", (0.0, 1.0), "a contact straying farther is split by a flight (ours)")
    constraints: tuple[str, ...] = setting(TRAJOPT_CONSTRAINTS, choices=TRAJOPT_CONSTRAINTS, help="sets used (C.2)")
    dynamics_interval: float = setting(0.1, "s", (0.0, 1.0), "between Newton-Euler constraints; 0: every frame")
    internal_momentum: bool = setting(True, help="Euler's equation counts the limbs' momentum about the COM (ours)")
    linear_dynamics_interval: float = setting(1.0 / 60.0, "s", (0.0, 1.0),
                                            "Newton samples: frames, this apart; faster frames: this (ours); 0: frames")
    kinematic_interval: float = setting(0.08, "s", (0.0, 1.0), "between foot- and leg-length constraints")
    floor_interval: float = setting(0.1, "s", (0.0, 1.0), "between above-floor constraints of feet in flight")
    contact_change_reach: float = setting(2.0, "knot intervals", (0.0, 10.0), "COM knots this near a change: only C1")
    boundary_seconds: float = setting(1 / 6, "s", (0.01, 3.0), "COM velocity at the ends: the mean over this (C.2)")
    max_force: float = setting(1000.0, "N", (10.0, 1e5), "f_max: largest normal force of one contact point")
    friction: float = setting(0.5, "", (0.05, 2.0), "mu of the friction pyramid")
    gravity: float = setting(9.81, "m/s^2", (0.0, 30.0), "(paper 9.8)")
    costs: tuple[str, ...] = setting(TRAJOPT_COSTS, choices=TRAJOPT_COSTS, help="terms used (equations 1-4)")
    weight_com: float = setting(0.8, "1/m^2", (0.0, 1e4), "w_r (paper 0.4): the upper body rides on the COM")
    weight_orientation: float = setting(1.7, "1/rad^2", (0.0, 1e4), "w_theta")
    weight_feet: float = setting(0.3, "1/m^2", (0.0, 1e4), "w_p")
    weight_duration: float = setting(0.1, "1/s^2", (0.0, 1e4), "w_d")
    velocity_com: float = setting(1e-3, "s^2/m^2", (0.0, 1e4), "gamma_r")
    velocity_orientation: float = setting(1e-3, "s^2/rad^2", (0.0, 1e4), "gamma_theta")
    velocity_feet: float = setting(0.1, "1/(m/step)^2", (0.0, 1e4), "gamma_p, per 1/30 s step")
    acceleration_com: float = setting(1e-5, "s^4/m^2", (0.0, 1e4), "beta_r (paper 1e-4: a 1.3 Hz low pass)")
    acceleration_orientation: float = setting(1e-5, "s^4/rad^2", (0.0, 1e4), "beta_theta (paper 1e-4)")
    acceleration_feet: float = setting(1e-4, "1/(m/step^2)^2", (0.0, 1e4), "beta_p")
    optimize_durations: bool = setting(False, help="C.3's last stage, free phase durations (10x the time)")
    max_duration_change: float = setting(0.1, "s", (0.0, 1.0), "each phase boundary may move there (ours)")
    tolerance: float = setting(1e-6, "", (1e-10, 1.0), "IPOPT tol (looser: the COM wiggles, standing forces err)")
    max_iterations: int = setting(1000, "", (1, 100000), "IPOPT iterations per window, its stages and restart together")
    max_seconds: float = setting(120.0, "s", (0.1, 1e5), "CPU-time limit of one IPOPT run (not wall: load-proof)")
    reject_departure: float | None = setting(0.3, "m", (0.01, 10.0), "windows whose COM strays farther from the "
                                             "input on any kept frame are not used (ours; None: all kept)")
    window_seconds: float = setting(4.0, "s", (0.5, 600.0), "long clips are solved in windows this long (ours)")
    window_overlap: float = setting(1.0, "s", (0.0, 300.0), "a window looks beyond what it keeps; <= window_seconds/2")
    parallel_windows: bool = setting(False, help="solve windows two at a time (docs/decisions/trajopt-long-clips.md)")
    rotate_upper_body: bool = setting(True, help="C.4: upper body turns with the optimised orientation (ours)")
    ik_feet_weight: float = setting(100.0, "", (0.01, 1e6), "of the heel and toe targets against the upper body's")
    ik_leg_weight: float = setting(1.0, "", (0.0, 1e6), "of the knees' and ankles' offsets (ours; paper 0)")
    ik_iterations: int = setting(20, "", (1, 200), "Levenberg-Marquardt iterations of the IK")
    force_rate: float = setting(1e-5, "(body weights/s)^-2", (0.0, 1e4), "w_f of the force_rate cost (ours)")

    def check(self):
        super().check()
        if self.window_overlap > self.window_seconds / 2:
            raise SettingsError(f"trajopt.window_overlap = {self.window_overlap} is out of range: expected at most "
                                f"window_seconds / 2 = {self.window_seconds / 2} s.")
        return self


@dataclass(frozen=True)
class Settings(Section):
    body: BodySettings = field(default_factory=BodySettings)
    camera: CameraSettings = field(default_factory=CameraSettings)
    detect: DetectSettings = field(default_factory=DetectSettings)
    fit: FitSettings = field(default_factory=FitSettings)
    physics: PhysicsSettings = field(default_factory=PhysicsSettings)
    trajopt: TrajoptSettings = field(default_factory=TrajoptSettings)
    online: bool = setting(False, help="causal per-frame fit (live use) instead of the whole clip at once")
    overlay_width: int = setting(1280, "px", (160, 7680), "overlay.mp4 at most this wide (0: the video's)", also=0)
    overlay_parts: int | None = setting(None, "", (1, 2), "overlay.mp4 drawn and encoded in this many parts at once "
                                        "(None: 2 for 150 frames or more where the process has 2 cores)")

    def check(self) -> Settings:
        super().check()
        if self.physics.method == "trajopt" and self.online:
            raise SettingsError("physics trajopt optimises the whole clip: it cannot run --online (use physcap).")
        return self

    @property
    def refines_before_physics(self) -> bool:
        """Whether the physics starts from B.4's refinement of the clip: trajopt always, PhysCap offline by default."""
        method = self.physics.method
        return method == "trajopt" or (method == "physcap" and self.physics.refine_offline and not self.online)


def load_settings(path: str | Path | None = None) -> Settings:
    """Defaults, overridden by a TOML file if given."""
    return Settings() if path is None else load_toml(Settings, Path(path))
