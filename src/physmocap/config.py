"""Typed settings. Every field states its unit and sensible range; defaults are the papers' values where they
give one. Override from a TOML file (`--config`) with the same section and field names, e.g.

    [fit]
    weight_depth = 0.5
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

from .errors import InputError, SettingsError


@dataclass(frozen=True)
class BodySettings:
    height: float = 1.70  # m, the person's standing height; 1.0 .. 2.3
    mass: float = 70.0  # kg, the person's mass; 20 .. 250
    calibration_frames: int = 0  # frames whose 3D landmarks set the bone lengths; 0: all (offline; the online fit
    # calibrates on its first 3 s); 1 .. 10000. All frames: synthetic root-relative error 37.1 -> 33.5 mm (measured)
    estimate_height: bool = False  # true: the height is read from the detector's 3D landmarks as metres
    # (kinematics.calibration.estimate_height) instead of `height`, which stays the fallback; see BENCHMARKS.md,
    # "Floor, other detectors and height (issue 17)", for how metric MediaPipe's landmarks are on real video

    def check(self) -> None:
        _within("body.height", self.height, 1.0, 2.3, "m")
        _within("body.mass", self.mass, 20.0, 250.0, "kg")
        _within("body.calibration_frames", self.calibration_frames, 0, 100000, "frames")


@dataclass(frozen=True)
class CameraSettings:
    focal: float | None = None  # px, focal length; overrides fov
    fov: float | None = None  # degrees across the longer image side; 10 .. 160 (default 60 when neither given)
    floor: tuple[float, float, float, float] | None = None  # plane n.x + d = 0 in the camera frame, metres

    def check(self) -> None:
        if self.focal is not None:
            _within("camera.focal", self.focal, 1.0, 1e6, "pixels")
        if self.fov is not None:
            _within("camera.fov", self.fov, 10.0, 160.0, "degrees")
        if self.floor is not None:
            _check_floor(self.floor)


@dataclass(frozen=True)
class DetectSettings:
    max_width: int | None = None  # px, downscale wider search regions to this for the detector (None: native);
    # native was as fast and more accurate on the shared videos when the person is small in the frame; 160 .. 4096
    person_box: tuple[float, float, float, float] | None = None  # px x0,y0,x1,y1: follow the person inside
    accept_truncated: bool = False  # capture the decodable part of a truncated video instead of stopping

    def check(self) -> None:
        if self.max_width is not None:
            _within("detect.max_width", self.max_width, 160, 4096, "pixels")
        if self.person_box is not None:
            if len(self.person_box) != 4:
                raise InputError(f"detect.person_box must be four numbers x0,y0,x1,y1, got {self.person_box}.")
            x0, y0, x1, y1 = self.person_box
            if not (x1 > x0 and y1 > y0):
                raise InputError("detect.person_box must be x0,y0,x1,y1 with x1 > x0 and y1 > y0, "
                                 f"got {self.person_box}.")


@dataclass(frozen=True)
class FitSettings:
    """Kinematic fit, PhysCap eq. (3). Residuals are in metres (2D errors are scaled to the person's depth),
    so the weights compare directly. Temporal terms are stated at 30 fps and rescaled to the clip's rate."""

    weight_2d: float = 1.0  # E_proj: reprojection; 0 .. 100
    weight_3d: float = 0.3  # E_IK: root-relative 3D landmarks; 0 .. 100
    weight_smooth: float = 0.1  # E_smooth: acceleration of the joints; 0 .. 100
    weight_depth: float = 0.03  # E_depth: change of the joints' depth along the camera axis; 0 .. 100
    weight_prior: float = 1e-4  # pull of ball joints towards a neutral pose, resolves twists; 0 .. 1
    weight_limits: float = 10.0  # hinge joint limits; 0 .. 1000
    limit_band: float = 0.2  # rad: the hinge limits' penalty is rounded off within this angle of the limit, so
    # that Levenberg-Marquardt sees a limit coming instead of stepping across its kink (offline fit's steps
    # rejected on sports2d 3 -> 1, taiji 4 -> 1). It also keeps elbows away from bending backwards: synthetic set
    # (8 clips x 2 seeds) root-relative 31.9 -> 31.2 mm offline, 50.3 -> 49.3 mm online, but 0.05 / 0.1 / 0.15
    # / 0.25 gave 32.8 / 34.8 / 31.5 / 31.4 mm offline (arms settling on either side of the elbow ambiguity);
    # 0 .. 1
    hand_weight: float = 0.25  # factor on both data terms of the hand's own markers (pinky and index knuckles),
    # which only turn the hand and are among the detector's noisiest points (physmocap.contacts.noise measured 1.3-1.5
    # times the mean error on the right hand, 0.8 on the left); they pulled the wrists and elbows. Synthetic set
    # (8 clips x 2 seeds), offline root-relative: 1 -> 31.2 mm, 0.25 -> 30.4 mm (3D only: 30.6), 0.0625 (3D) with
    # 0.25 (2D) 30.4 mm; 0 .. 1
    min_confidence: float = 0.1  # keypoints below this confidence are ignored; 0 .. 1
    robust_2d: float = 0.05  # m at the person's depth: reprojection errors beyond this count linearly (Huber);
    # 0 disables; 0 .. 1
    robust_3d: float = 0.10  # m (weighted): 3D landmark errors beyond this count linearly; 0 disables; 0 .. 1
    offline_iterations: int = 8  # Levenberg-Marquardt iterations over the whole clip; 1 .. 200
    online_iterations: int = 4  # Levenberg-Marquardt iterations per frame when causal; 1 .. 50
    offline_start_iterations: int = 2  # the same for the causal fits that start the offline fit, which refines
    # them anyway (synthetic set, 8 clips x 2 seeds: 4 -> 2 took root-relative 32.4 -> 32.1 mm, global root 45.1
    # -> 47.5 mm, 1 gave 34.5 / 61.3 mm); 1 .. 50
    undo_foot_swaps: bool = True  # find where the detector swapped the left and right feet and fit them back
    # (detect.foot_swaps): offline and in the online warm-up from knees joined to the other side's ankles and feet
    # jumping to each other's place; online after it, the reading that better fits the pose predicted from the past
    rescale_landmark_depth: bool = True  # offline: undo the detector's per-frame stretch of its 3D landmarks along
    # the camera axis, measured against the initial fit (stage.landmark_depth_scale)
    refine_lengths: bool = True  # measure the limbs' and feet's lengths again along the axes of a first fit
    # (kinematics.stage.refine_lengths): offline before the whole-clip fit, online on the warm-up, which is then
    # fitted again. Synthetic set (8 clips x 2 seeds), offline: root-relative 30.4 -> 28.1 mm, global root 43.1 ->
    # 39.3 mm (the true lengths instead: 26.4 mm); online 35.6 -> 33.5 mm, 118.4 -> 118.9 mm. Real videos,
    # reprojection offline taiji 5.56 -> 5.00 px, sports2d 5.02 -> 5.45 px; online 5.60 -> 5.20, 6.49 -> 5.85 px.
    # From the 3D landmarks alone: 28.2 mm offline, but 5.85 / 6.85 px; the limbs alone: 29.7 mm
    offline_chunk: int = 32  # frames: the offline fit starts from causal fits of runs this long, all run side by
    # side (one batched step per frame; shorter runs: more cold starts, fewer steps); 2 .. 100000
    one_euro: bool = False  # One-Euro filter on the fitted pose (Casiez et al. 2012)
    one_euro_min_cutoff: float = 1.5  # Hz; 0.01 .. 30
    one_euro_beta: float = 0.3  # speed coefficient; 0 .. 10
    # Optional terms of Rempe et al. 2020 (B.3), all off by default (the trajopt stage turns them on with the
    # paper's weights, TrajoptSettings.kinematic_*). Residuals in metres (radians for angles), stated at 30 fps.
    weight_contact_velocity: float = 0.0  # E_cont (B6): heel/toe motion between two frames both in contact;
    # offline fit only; paper 10; 0 .. 1000
    weight_floor: float = 0.0  # E_floor (B7): heel/toe height above the floor plane while in contact; paper 10;
    # 0 .. 1000
    weight_velocity: float = 0.0  # E_vel (B2): velocity of the pelvis-relative joint positions; paper 0.1; 0 .. 100
    weight_angle_velocity: float = 0.0  # E_ang (B3): change of the joint angles (ball joints' rotation vectors
    # and hinge angles, not the root) between frames; paper 0.1; 0 .. 100

    def check(self) -> None:
        for name in ("weight_2d", "weight_3d", "weight_smooth", "weight_depth", "weight_prior", "weight_limits",
                     "weight_contact_velocity", "weight_floor", "weight_velocity", "weight_angle_velocity"):
            _within(f"fit.{name}", getattr(self, name), 0.0, 1000.0, "")
        _within("fit.min_confidence", self.min_confidence, 0.0, 1.0, "")
        _within("fit.robust_2d", self.robust_2d, 0.0, 1.0, "m")
        _within("fit.limit_band", self.limit_band, 0.0, 1.0, "rad")
        _within("fit.hand_weight", self.hand_weight, 0.0, 1.0, "")
        _within("fit.robust_3d", self.robust_3d, 0.0, 1.0, "m")
        _within("fit.offline_iterations", self.offline_iterations, 1, 200, "")
        _within("fit.online_iterations", self.online_iterations, 1, 50, "")
        _within("fit.offline_start_iterations", self.offline_start_iterations, 1, 50, "")
        _within("fit.offline_chunk", self.offline_chunk, 2, 100000, "frames")
        _within("fit.one_euro_min_cutoff", self.one_euro_min_cutoff, 0.01, 30.0, "Hz")
        _within("fit.one_euro_beta", self.one_euro_beta, 0.0, 10.0, "")


@dataclass(frozen=True)
class PhysicsSettings:
    """Physics after the kinematic fit. PhysCap stage III (Shimada et al. 2020, 4.3 and 5.1) for "physcap"."""

    method: str = "physcap"  # "physcap" (per frame; the default: docs/decisions/physics-default.md), "trajopt"
    # (Rempe et al., whole clip) or "none" (kinematics only)
    refine_offline: bool = True  # offline runs: PhysCap tracks the kinematics after Rempe's B.4 refinement (the
    # one trajopt starts from: contact velocity, smoothing and floor terms, trajopt.kinematic_* weights) instead
    # of the plain fit; online runs cannot (it needs the whole clip). Synthetic set (8 clips x 2 seeds):
    # root-relative 35.1 -> 29.2 mm, e_smooth 9.6 -> 6.2 mm, MPE 23.3 -> 16.4 mm, PNP 88.5 -> 93.4%, skate 5.7 ->
    # 1.4%; ten other CMU clips x 2 seeds: 45.5 -> 35.5 mm, 12.2 -> 8.7 mm, 28.6 -> 21.1 mm, 74.9 -> 84.1%, 5.2 ->
    # 1.4%; taiji video: jitter 15.5 -> 9.8 m/s^2, reprojection 12.9 -> 9.6 px. Costs about 2.5 ms per frame
    stray_distance: float = 0.15  # m: frames whose final joints lie farther than this on average from the
    # kinematic motion's are reported (summary.json physics_strayed_frames, a warning): the physics could not
    # follow there, e.g. a floor that does not fit the scene or wrong contacts. Taiji: at most 0.14 m online;
    # sports2d, whose man jumps off a roof onto ground 1.9 m lower, 71 frames beyond; 0.01 .. 10
    kp_joint: float = 1200.0  # 1/s^2, PD gains of the joints (paper 5.1: 300 and 20); 0 .. 1e4. The paper's
    # gains (damping ratio 0.58) let the character lag the motion: on the synthetic set's online fits the physics
    # lost 8 mm of root-relative accuracy even without contacts. Critically damped at 4x the stiffness, joints and
    # root rotation together (either alone did not help): root-relative 61.2 -> 58.0 mm (second seed 59.4 -> 53.6,
    # offline 40.1 -> 36.0), e_smooth 16.2 -> 17.3 mm, residual 29% -> 40% of body weight. Cost: a pushing-off toe
    # held closer to the floor touches it in the odd frame the labels call flight (ballistic GRF on the first seed
    # with the 1.0 m/s labels: 0% -> 54%, from 1-2 frames in each of 3 clips)
    kd_joint: float = 70.0  # 1/s
    kp_root_rotation: float = 1200.0  # 1/s^2 (paper: 340 and 30)
    kd_root_rotation: float = 70.0  # 1/s
    kp_root_translation: float = 1000.0  # 1/s^2
    kd_root_translation: float = 80.0  # 1/s
    acceleration_feedforward: float = 0.5  # share of the kinematic acceleration fed forward in eq. (4) (paper: 1).
    # A per-frame fit's second differences carry about as much noise as motion; shrinking them by half took the
    # synthetic set's root-relative error from 81 to 78 mm, e_smooth from 22 to 19 mm and the residual from 60% to
    # 47% of body weight, and changed nothing on noise-free input; 0 .. 1
    velocity_smoothing: float = 0.03  # s, time constant of the causal exponential smoothing of the kinematic
    # velocity (q_dot_kin of eq. 4, and the acceleration fed forward from it); 0: plain backward differences. The
    # derivative term passes the difference of two noisy poses straight into the desired acceleration: without
    # it physics added jitter to its input (taiji, 24 fps, online: 16.5 -> 19.9 m/s^2 mean joint acceleration,
    # with 0.03 s 17.4; 0.045 s gave 16.1; offline 8.6 -> 9.9, with 0.03 s 9.1). Synthetic set (floor estimated
    # / calibrated): e_smooth 13.0 / 12.8 -> 11.8 / 11.7 mm, root-relative error +0.2 / +0.1 mm; chosen on ten
    # CMU clips outside the test subjects (0.02-0.08 s tried; longer ones smooth more and lag more); 0 .. 1
    rotation_velocity_share: float = 0.8  # share of the kinematic target's rotational velocities (the root's
    # orientation and every joint) in eq. (4)'s derivative term, the rest of kd damping the character's own
    # rotation (paper: 1; ours). The velocity of a noisy per-frame fit is half noise, and kd passed it on:
    # without contacts or root limits the tracker alone added jitter to its input (synthetic set, online fit:
    # e_smooth 10.7 -> 11.1 mm), where a plain causal smoothing of the joints removes some (8.9 mm). The root's
    # translation keeps its full velocity (scaled, a walking root trails its target by a steady 5 mm: global
    # root error +5 mm); scaling the joints without the root's orientation, or the reverse, lost (root-relative
    # 39.3 / 39.9 against 36.7 mm), the limbs' directions then following two different velocities. Ten CMU clips
    # of other subjects, calibrated floor, shares 1 / 0.9 / 0.85 / 0.8 / 0.7: root-relative 39.8 / 37.8 / 37.4 /
    # 37.5 / 38.7 mm, e_smooth 13.4 / 12.5 / 12.3 / 11.7 / 11.3 mm, MPE 27.3 / 26.4 / 26.0 / 24.1 / 22.3 mm,
    # global root 97.7 / 97.4 / 97.8 / 96.4 / 95.5 mm (estimated floor, 1 / 0.8: 39.2 -> 37.1 mm, e_smooth
    # 12.7 -> 11.5 mm). With 0.8 a velocity smoothing of 0.015 / 0.045 s lost (37.6 / 38.1 mm); 0 .. 1
    contact_height: float = 0.1  # m, psi of eq. (5): a predicted contact counts only below this height; 0 .. 1
    target_lift_time: float | None = 0.1  # s: a kinematic target whose lowest predicted contact point lies
    # under the floor is raised by that depth, the lift following the target's feet with this time constant and
    # held while no contact within contact_height is predicted (ours; None: the target as it comes, as the paper).
    # The character's feet cannot follow a kinematic foot into the floor, so the stiff root PD pulled a body the
    # floor held up towards free fall, and the residual carried what the forces then lacked (online fits, true
    # floor: physics root 6.5 mm above its target on average, vertical residual 10% of body weight). Synthetic
    # set, calibrated / estimated floor: root-relative 37.8 -> 36.6 / 38.8 -> 36.8 mm, e_smooth 11.5 -> 11.2 /
    # 11.7 -> 11.3 mm, skate 9.3 -> 8.0 / 10.2 -> 8.2%, residual 31 -> 21 / 34 -> 22% of body weight, mean GRF on
    # walks 94.7 -> 103.5 / 95.2 -> 103.8%, MPE 22.2 -> 26.2 / 26.3 -> 30.9 mm (a foot no longer pressed flat by
    # the conflict keeps its fitted tilt); ten CMU clips of other subjects 47.3 -> 40.4 / 47.7 -> 39.7 mm (their
    # run 73 -> 38 mm, uneven ground 65-72 -> 34-42 mm). Time constant 0.05 / 0.2 s, calibrated floor: 36.5 /
    # 36.7 mm (other clips 40.0 / 41.2), walks 104.5 / 102.6%. Moving the target down onto the floor as well
    # (feet above it): 36.7 / 40.7 mm, MPE 20.1 / 30.7 mm, but force in more of the other clips' flight frames;
    # lifting by the mean or the highest contact point lost. Cost: the fit's contact points disagree by a few cm
    # (taiji online: 3.4 cm median spread), so the others float: taiji online, floating 18 -> 41% of contact
    # frames, reprojection 12.9 -> 16.7 px, residual 41 -> 19% of body weight, mean GRF 88 -> 108%; lifting by
    # the mean depth of the points under the floor instead: 31%, 14.4 px, 32%, 95% (synthetic walks' GRF 92%,
    # root-relative 36.7 / 40.1 mm); 0.001 .. 10
    flatten_feet: bool = True  # with target_lift_time (and its time constant): a target foot whose heel and
    # toe are both predicted in contact is turned flat about the ankle before the lift, so that the lift does not
    # leave its higher point floating (ours). Synthetic set, calibrated / estimated floor: MPE 26.6 -> 25.3 /
    # 31.5 -> 28.1 mm, PNP 98.1 -> 98.3 / 79.8 -> 83.1%, floating 22.0 -> 19.3 / 25.7 -> 21.9%, root-relative
    # 36.5 -> 36.7 / 36.6 -> 36.6 mm, e_smooth 11.1 -> 11.2 / 11.3 -> 11.3 mm; taiji online: floating 41 -> 33%,
    # MPE 35 -> 29 mm, reprojection 16.7 -> 13.8 px. Cost: offline, on the B.4 motion whose feet B.4 already
    # placed, floating 4.0 -> 5.7%, MPE 15.6 -> 16.3 mm; and about 5% of the stage's time. Turning at once
    # instead of smoothly: e_smooth +0.25 mm
    friction: float = 0.8  # mu; the pyramid uses mu / sqrt(2) (eq. 7); 0.05 .. 2
    slide_speed: float = 0.3  # m/s, sigma of eq. (9): tangential speed a contact may keep (paper: not given). On
    # the synthetic set 0.05 (PhysCap's contact-labelling speed) nearly locks the feet, and wherever the predicted
    # contacts or the kinematic feet are off, the locked foot drags the body: root-relative error 127 mm against 102
    # at 0.3 (noise-free input: 50 against 24 mm), skate still under the kinematic input's; 0 .. 1
    step: float | None = None  # s, phi of eq. (1); None: one frame / iterations (the paper's 0.01 s at 25 fps)
    iterations: int = 4  # n, steps ii-v per frame; 1 .. 50
    torque_weight: float = 4.5e-4  # weight of |tau|^2 against |qdd - qdd_des|^2 (authors' release); 0 .. 1
    residual_weight: float = 3e-3  # weight of the root's direct actuation |tau_root|^2; with 4.5e-4 (the joints'
    # value, tuned by the authors for a 40 kg character) a 70 kg root reaches only a third of its desired
    # acceleration and on the demo clip the residual averaged 150% of body weight (1e-3: 76%, 1e-2: 28%, but then
    # a leaning stationary pose can no longer be brought back to balance); 0 .. 1e3
    residual_weight_vertical: float = 1e-2  # the same for its vertical force: the body's weight belongs on the feet
    # (ours). At 3e-3 the residual carried 12% of the weight on the synthetic walks (mean GRF 86-88%). With the
    # stiffer joint gains 1e-2 let the mean GRF fall to 83% and 3e-2 was needed for 96%; with target_lift_time
    # the floor no longer holds the feet against the target, and 1e-2 gives walks 98.4% (3e-2: 103.5%, 5e-3:
    # 96.0%), root-relative 36.5 mm (36.6), ten CMU clips of other subjects 39.7 mm (40.4), residual 23% of body
    # weight (21%) (calibrated floor); 0 .. 1e3
    foot_lock: str = "auto"  # auto: the predicted contacts; always: every sole point within contact_height of the
    # floor; never: no contacts and no floor collisions (airborne or swimming motion)
    penetration_recovery: float = 0.1  # s, a contact point found below the floor rises back at depth / this time
    # (pushing it out within one step launches the body); 0.001 .. 1
    release_distance: float | None = 0.05  # m: a contact whose kinematic target lies farther than this along the
    # floor from the character's contact point is released: no predicted contact there, and a foot touching the
    # floor may slide but not sink (ours; None: never, as the paper). Holding a foot the detector has moved
    # elsewhere drags the body: on the synthetic set's offline fits 0.05 m took the root-relative error from 82 to
    # 45 mm and the residual from 44% to 35% of body weight (0.1 m: 48 mm; 0.03 m: skate over the input's); 0 .. 1
    touch_margin: float = 0.003  # m: a sole point this close to the floor counts as colliding with it in eq. (5)
    # (paper: touching). Caught only once under the floor, a swinging foot stayed there for the recovery time; on
    # the synthetic set with the true floor, PNP 91.5% -> 93.6% (5 mm: 93.3%), nothing else changed; 0 .. 0.1
    floor_clearance: float = 0.0005  # m: the physics' floor lies this far above the floor plane (ours). The
    # contact constraints are linear in the step; the feet's rotation over a step then dips resting points a
    # fraction of a millimetre under the floor, which PNP counts (median depth 0.06-0.4 mm): PNP 93.6% -> 97.4%
    # with the true floor, MPE +0.1 mm; 0 .. 0.01
    floor_refit_interval: float | None = 3.0  # s between refits of the floor while online (ours; None: the
    # warm-up's floor is kept). A warm-up spent standing gives clustered foot points and a floor tilted 2-5
    # degrees on some synthetic clips; refitted to the kinematic contact points as frames arrive, the online
    # PhysCap's PNP rose from 79% to 89% and penetration fell from 1.3% to 0.1%, MPE 34.9 -> 37.2 mm (at 1 s,
    # before the causal foot-swap check). A refit costs about 6 ms: every 3 s instead of every second keeps the
    # stage near 1000 frames/s and changed PNP by -0.8 / -1.5 points on the two seeds, MPE by +0.1 / -0.3 mm;
    # 0.1 .. 60
    floor_refine_after: float = 3.0  # s of frames before the first refit (the warm-up's floor came from as
    # many; refitting from 1 s on was worse: PNP 88.4%, MPE 40.7 mm); 0 .. 60
    floor_tilt_rate: float = 1.0  # deg/s: the fastest the refined floor turns (the character's targets turn with
    # it; 3 deg/s changed nothing measurable); 0.01 .. 90
    floor_lift_rate: float = 0.05  # m/s: the fastest the refined floor moves along its normal; 0.001 .. 1
    balance_correction: bool = True  # 4.3.1: straighten stationary poses whose centre of mass leaves the support
    correction_rate: float = 0.1  # fraction of the remaining lean corrected per frame (paper: theta / 10); 0 .. 1
    stationary_max_speed: float | None = 0.25  # m/s: the contact stage's stationary flag is believed only while
    # the kinematic root has moved slower than this over the last stationary_speed_interval (ours; None: always,
    # as the paper). The labels' own threshold (contacts.labels). The causal network calls a sideways dribble
    # stationary in a third of its frames, and the correction then tilted a moving body: synthetic set,
    # calibrated floor, root-relative 38.5 -> 37.8 mm (006_08: 57.6 -> 48.9), estimated 39.3 -> 38.8 mm; ten CMU
    # clips outside the test subjects 48.5 -> 47.3 mm; 0.4 m/s kept less of the gain (37.8 / 48.3); 0.01 .. 10
    stationary_speed_interval: float = 0.2  # s over which that speed is measured, ending at the frame (the
    # labels measure it over 0.2 s centred on the frame); 0.01 .. 2
    max_step: float | None = 0.011  # s: the longest integration step; each frame is split into the fewest equal
    # steps of at most this (ceil(frame interval / max_step)), so that 8-120 fps inputs integrate alike (ours;
    # None: `iterations` steps per frame whatever its length). Semi-implicit Euler on the PD is stable only while
    # kp h^2 + 2 kd h < 4, h < 0.022 s at the root's gains; half that keeps the paper's 4 steps at 24-30 fps.
    # The fixed 4 steps per frame gave 0.025 s steps at 10 fps: a real 10 fps video reached 100 times body weight.
    # Details: docs/decisions/physics-frame-rate.md; 0.001 .. 0.02
    max_force: float = 10.0  # body weights: the largest contact force (the frame's sum) and residual root force
    # written (the residual torque: this times body weight times 1 m); beyond it they are scaled down and the frame
    # is flagged unexplained. A running human's peak vertical force is 2-3 body weights, a drop landing about 5-8
    # (ours); 1 .. 100
    unexplained_force: float | None = 0.5  # body weights: frames whose upward root force that the kinematic motion
    # needs and no contact on the floor can give (eq. 6's misfit), averaged over unexplained_time, exceeds this
    # (more than half the weight carried by something else: hands, a raised floor) are flagged unexplained and
    # handed back as the kinematic motion (ours; None: no such diagnosis, while a QP failure, a diverged step, a
    # force over max_force or a pose farther than stray_distance are still flagged). A 0.3 m box under synthetic
    # walks: 88-94% of its frames flagged, none of the same walks without it. docs/decisions/physics-limits.md;
    # 0.05 .. 10
    unexplained_time: float = 0.2  # s, time constant of that average; 0.01 .. 2
    unexplained_blend: float = 0.2  # s over which the output passes from the physics to the kinematic motion and
    # back around flagged frames (no jump); 0 .. 2

    def check(self) -> None:
        if self.method not in ("none", "physcap", "trajopt"):
            raise InputError(f"physics.method must be none, physcap or trajopt, got '{self.method}'.")
        if self.foot_lock not in ("auto", "always", "never"):
            raise InputError(f"physics.foot_lock must be auto, always or never, got '{self.foot_lock}'.")
        for name in ("kp_joint", "kd_joint", "kp_root_rotation", "kd_root_rotation", "kp_root_translation",
                     "kd_root_translation"):
            _within(f"physics.{name}", getattr(self, name), 0.0, 1e5, "")
        _within("physics.contact_height", self.contact_height, 0.0, 1.0, "m")
        if self.target_lift_time is not None:
            _within("physics.target_lift_time", self.target_lift_time, 0.001, 10.0, "s")
        _within("physics.friction", self.friction, 0.05, 2.0, "")
        _within("physics.slide_speed", self.slide_speed, 0.0, 1.0, "m/s")
        if self.step is not None:
            _within("physics.step", self.step, 1e-4, 0.1, "s")
        _within("physics.iterations", self.iterations, 1, 50, "")
        _within("physics.torque_weight", self.torque_weight, 0.0, 1.0, "")
        _within("physics.residual_weight", self.residual_weight, 0.0, 1e3, "")
        _within("physics.residual_weight_vertical", self.residual_weight_vertical, 0.0, 1e3, "")
        _within("physics.correction_rate", self.correction_rate, 0.0, 1.0, "")
        if self.stationary_max_speed is not None:
            _within("physics.stationary_max_speed", self.stationary_max_speed, 0.01, 10.0, "m/s")
        _within("physics.stationary_speed_interval", self.stationary_speed_interval, 0.01, 2.0, "s")
        if self.max_step is not None:
            _within("physics.max_step", self.max_step, 0.001, 0.02, "s")
        _within("physics.max_force", self.max_force, 1.0, 100.0, "body weights")
        if self.unexplained_force is not None:
            _within("physics.unexplained_force", self.unexplained_force, 0.05, 10.0, "body weights")
        _within("physics.unexplained_time", self.unexplained_time, 0.01, 2.0, "s")
        _within("physics.unexplained_blend", self.unexplained_blend, 0.0, 2.0, "s")
        _within("physics.acceleration_feedforward", self.acceleration_feedforward, 0.0, 1.0, "")
        _within("physics.velocity_smoothing", self.velocity_smoothing, 0.0, 1.0, "s")
        _within("physics.rotation_velocity_share", self.rotation_velocity_share, 0.0, 1.0, "")
        _within("physics.touch_margin", self.touch_margin, 0.0, 0.1, "m")
        _within("physics.floor_clearance", self.floor_clearance, 0.0, 0.01, "m")
        if self.floor_refit_interval is not None:
            _within("physics.floor_refit_interval", self.floor_refit_interval, 0.1, 60.0, "s")
        _within("physics.floor_refine_after", self.floor_refine_after, 0.0, 60.0, "s")
        _within("physics.floor_tilt_rate", self.floor_tilt_rate, 0.01, 90.0, "deg/s")
        _within("physics.floor_lift_rate", self.floor_lift_rate, 0.001, 1.0, "m/s")
        _within("physics.penetration_recovery", self.penetration_recovery, 1e-3, 1.0, "s")
        _within("physics.stray_distance", self.stray_distance, 0.01, 10.0, "m")
        if self.release_distance is not None:
            _within("physics.release_distance", self.release_distance, 0.0, 1.0, "m")


TRAJOPT_CONSTRAINTS: tuple[str, ...] = ("dynamics", "acceleration_continuity", "velocity_boundaries", "foot_length",
                                         "leg_length", "force_limits", "above_floor")
TRAJOPT_COSTS: tuple[str, ...] = ("data", "velocity", "acceleration", "duration", "force_rate")


@dataclass(frozen=True)
class TrajoptSettings:
    """Physics by trajectory optimisation over the whole clip, Rempe et al. 2020 (3.1, figure 3, appendices B and
    C). Defaults are the paper's values where it gives one; "ours" marks the others."""

    # Kinematic fit before the optimisation (B.3, B.4): weights of the fit's optional terms (FitSettings).
    kinematic_contact_velocity: float = 10.0  # alpha_cont; 0 .. 1000
    kinematic_floor: float = 10.0  # alpha_floor; 0 .. 1000
    kinematic_velocity: float = 0.1  # alpha_vel; 0 .. 100
    kinematic_angle_velocity: float = 0.1  # alpha_ang; 0 .. 100
    floor_outlier_distance: float = 0.05  # m: contacts farther from the fitted floor become no contact (ours: the
    # labels' own height limit, contacts.labels; at 0.10 points the network calls in contact while they are in the
    # air stayed in, and the floor term pulled them down: synthetic 131_02 kept 62 such flags, 8.8 cm up in the
    # truth (median), against 14 at 0.05; synthetic set (8 clips, seed 0), B.4 global MPJPE 46.1 -> 43.7 mm
    # (131_02 51.3 -> 37.0), trajopt 48.7 -> 45.8 mm); 0.01 .. 1
    floor_pitch_prior: float = 0.05  # weight of the B.4 floor normal's tilt from the kinematic stage's floor towards
    # or away from the camera, relative to one contact point at 1 m, per point (ours): monocular depth errors move
    # the contact points along the camera's rays, off the floor by (depth error) x (camera height) / depth, which
    # tilts a plane through them this way (measured with no prior: up to 17 degrees on synthetic walks and runs
    # of subjects 2 and 7); 0 .. 10
    floor_roll_prior: float = 0.002  # the same about the viewing direction (ours), which the image positions of the
    # feet fix: weak, as the prior (the body's mean vertical axis) leans with the person. At 0.05 (the pitch's
    # weight) a person leaning sideways rolled the floor 8 degrees (synthetic 006_08, held-out subject 6; 4-7 at
    # 0.002; the B.4 motion's penetration of the true floor over the 16 test cases 0.38 -> 0.11%); on clips of
    # subjects 2, 5, 7 and 1 the mean error 1.05 -> 0.72 degrees (002_04 3.6 -> 1.8); 0 .. 10
    contact_slip_speed: float = 1.2  # m/s: contacts whose point slides faster than this in the kinematic motion
    # become no contact (ours: twice Rempe's 0.6 m/s label speed, for the fit's noise; physmocap's own labels
    # allow 1.0 m/s, contacts.labels); 0 (off) .. 100
    contact_slip_interval: float = 0.1  # s over which that speed (and rest_speed) is measured; 0.01 .. 1
    rest_height: float = 0.02  # m: points labelled in the air but lower than this (under the floor too) and
    # slower than rest_speed for min_phase_seconds become contacts (ours: under half the labels' 5 cm); 0 (off) .. 0.5
    rest_speed: float = 0.6  # m/s: Rempe's label speed (3.2; at 0.3 the noisy fit of a planted foot flickered in
    # and out, measured: 131_01 global error 84 -> 74 mm); 0 .. 10
    # Parameterisation (C.1).
    com_interval: float = 0.05  # s between the knots of the COM position and orientation polynomials (the paper:
    # 0.1; with the C2 COM of `acceleration_continuity`, 0.1 s knots cost 12% body error where contact labels are
    # wrong, measured); 0.02 .. 1
    segments_per_phase: int = 6  # at least this many polynomials per foot flight and per contact force phase;
    # 1 .. 50
    segment_phase_seconds: float = 2.0  # s: phases longer than this get proportionally more polynomials; 0.1 .. 60
    min_phase_seconds: float = 0.06  # s: shorter runs of contact flags merge into their neighbours (ours; one
    # flickering frame at 30 fps); 0 .. 1
    contact_drift: float = 0.05  # m: a contact run whose point strays farther than this from its median position
    # in the input motion is split by a flight of min_phase_seconds (phases.split_drifting; ours: no slip holds a
    # phase's point still, and the synthetic set's CMU 131 feet drift up to 25 cm within labelled contacts).
    # Synthetic set (8 clips, seed 0), global MPJPE 46.9 -> 45.8 mm against the B.4 input's 43.7 (131_03 43.3 ->
    # 40.0); skate 1.0 -> 1.9% (the motion capture's own: 1.9%), max GRF 175 -> 196% BW; 0 (off) .. 1
    # Constraints (figure 3, C.2); a sample interval of 0 means every frame.
    constraints: tuple[str, ...] = TRAJOPT_CONSTRAINTS  # constraint sets used, by name
    dynamics_interval: float = 0.1  # s between dynamics constraints (Newton and Euler); 0 .. 1
    internal_momentum: bool = True  # Euler's equation also pays for the angular momentum the input's limbs swing
    # about the COM (ours; the paper's single rigid body turns only with the root: see
    # trajopt.reduced.internal_torque; measured with the paper's smoothing, synthetic walk 131_01 seed 0: global
    # MPJPE 61.3 -> 59.5 mm, 131_03 47.6 -> 47.6 mm)
    linear_dynamics_interval: float = 1.0 / 60.0  # s between Newton's equation (ours: twice per frame at 30 fps,
    # three samples per COM polynomial). With the paper's 0.1 s the forces between samples are free, and read at
    # the frames they averaged 241% of body weight on the synthetic clips (measured); Euler's equation that
    # often over-constrains the orientation polynomials (IPOPT stalls); 0 (every frame) .. 1
    kinematic_interval: float = 0.08  # s between foot-length and leg-length constraints; 0 .. 1
    floor_interval: float = 0.1  # s between above-floor constraints of feet in flight; 0 .. 1
    contact_change_reach: float = 2.0  # COM knot intervals: `acceleration_continuity` leaves out the knots this
    # close to a contact's start or end, where the net force changes fast (ours). A C2 COM there could meet a
    # landing on one point, or a take-off, only by moving the body far from the input: synthetic 131_03 seed 1
    # (true floor) dipped the COM 17 cm before a hop, 39.7 -> 79.5 mm global MPJPE; with the knots left out 41.6.
    # 16 test cases, global MPJPE against the B.4 input: +4.6% -> +3.4% (estimated floor), +11.9% -> +3.9% (true
    # floor), no case worse; mean GRF 101.5 -> 98.5% BW, max 219 -> 156%. At 0.5: 131_03 seed 1 44.8 mm. At 1.0
    # a standing jump (tests/test_trajopt.py, take-off 0.1-0.2 s after the dip's lowest point) still converged
    # 12-35 cm from its input; at 2.0 1 cm, with the 16 test cases unchanged (+3.4% / +4.0%) and 16 cases of
    # subjects 1, 2, 5, 7 the same or better (005_11 seed 1 58.1 -> 55.7 mm); 0 .. 10
    boundary_frames: int = 5  # frames whose mean COM velocity the first and last velocity must match; 1 .. 100
    max_force: float = 1000.0  # N, f_max: largest normal force of one contact point; 10 .. 1e5
    friction: float = 0.5  # mu of the friction pyramid; 0.05 .. 2
    gravity: float = 9.81  # m/s^2 (the paper: 9.8); 0 .. 30
    # Costs (equations 1-4), terms chosen by name.
    costs: tuple[str, ...] = TRAJOPT_COSTS
    weight_com: float = 0.8  # w_r, 1/m^2 (ours: the paper 0.4; the IK carries the upper body on the optimised COM,
    # so a COM that strays from the observations moves 10 of the 16 joints scored. Synthetic set (8 clips, seed 0),
    # global MPJPE 41.5 -> 41.1 mm against the B.4 input's 39.3 (+5.6% -> +4.6%), every clip closer; max GRF 190 ->
    # 206% BW; at 1.6: 40.9 mm, 220%). The other camera and noise seed, not used to choose it: +5.4% -> +4.4%, max
    # GRF 225 -> 232%; 0 .. 1e4
    weight_orientation: float = 1.7  # w_theta, 1/rad^2
    weight_feet: float = 0.3  # w_p, 1/m^2
    weight_duration: float = 0.1  # w_d, 1/s^2
    # Smoothing: the COM's and orientation's derivatives per second, the feet's per 1/30 s step (ours; see
    # trajopt.formulation.FEET_SMOOTHING_STEP for why).
    velocity_com: float = 1e-3  # gamma_r, s^2/m^2
    velocity_orientation: float = 1e-3  # gamma_theta, s^2/rad^2
    velocity_feet: float = 0.1  # gamma_p, 1/(m per step)^2
    acceleration_com: float = 1e-5  # beta_r, s^4/m^2 (ours; the paper: 1e-4, which against w_r = 0.4 filters the
    # COM like a low pass at (w_r / beta_r)^(1/4) = 1.3 Hz, below a walk's step frequency: its bob and sway go, and
    # the COM departs from the observations; 1e-5 passes 2.2 Hz; measured on 4 synthetic clips with the internal
    # momentum: global MPJPE 52.3 mm against 52.8 at 3e-5, 51.3 at 3e-6 with larger forces)
    acceleration_orientation: float = 1e-5  # beta_theta, s^4/rad^2 (ours, as beta_r; the paper: 1e-4; 51.6 mm against
    # 52.3 mm with the paper's on the same clips)
    acceleration_feet: float = 1e-4  # beta_p, 1/(m per step^2)^2
    # Staged solve (3.1, C.3).
    optimize_durations: bool = False  # last stage: phase durations free, kept only if the objective improves (the
    # paper runs it; off here by default: on the synthetic clips it cut the objective by up to 28% but took 10x
    # as long as stages 1-2 together, as IPOPT crosses frames at every boundary move, measured)
    max_duration_change: float = 0.1  # s each phase boundary may move in that stage (ours); 0 .. 1
    tolerance: float = 1e-6  # IPOPT tol (the authors' code: 1e-3, with another scaling: at 1e-4 here the COM wiggles by
    # a millimetre and the forces of a person standing still by 10%); 1e-10 .. 1
    max_iterations: int = 1000  # IPOPT iterations per stage (the authors' code: 7000); 1 .. 100000
    max_seconds: float = 120.0  # CPU-time limit of one IPOPT run (CPU, not wall: under load a wall-clock limit cut
    # windows short and the result depended on the machine's load, sports2d_demo.mp4 at load 15-18); 0.1 .. 1e5
    reject_departure: float | None = 0.3  # m: a window that converges with its COM farther than this from the
    # input on average is not used; the kinematic motion is kept there and flagged, as where IPOPT does not
    # converge (ours: IPOPT's "acceptable" point can satisfy the constraints far from the data: a 0.7 s run under
    # the true-floor protocol converged 63 cm (COM) and 144 cm (feet) away, 619 mm global error; the synthetic
    # test set's windows depart 1.1 cm at most). None keeps every converged window; 0.01 .. 10
    # Long clips: windows solved in sequence, each starting in the state the previous one reached (ours).
    window_seconds: float = 4.0  # s of one window; 0.5 .. 600
    window_overlap: float = 1.0  # s each window looks beyond the part it keeps; 0 .. window_seconds / 2
    # Full-body output (C.4).
    rotate_upper_body: bool = True  # upper-body offsets from the COM turn with the optimised orientation (ours;
    # the paper adds them unrotated)
    ik_feet_weight: float = 100.0  # weight of the heel and toe targets against the upper body's; 0.01 .. 1e6
    ik_leg_weight: float = 1.0  # weight of the knees' and ankles' input offsets from the COM, as the upper body's
    # (ours; the paper: 0, free: the knees then swivel away, +16-20 mm knee error on synthetic clips, measured;
    # the contact points' 100 still decide); 0 .. 1e6
    ik_iterations: int = 20  # Levenberg-Marquardt iterations of the IK; 1 .. 200
    force_rate: float = 1e-5  # w_f of the `force_rate` cost, (body weights per second)^-2 (ours; see
    # docs/decisions/trajopt-force-chatter.md); 0 .. 1e4

    def check(self) -> None:
        for name in ("kinematic_contact_velocity", "kinematic_floor", "kinematic_velocity",
                     "kinematic_angle_velocity"):
            _within(f"trajopt.{name}", getattr(self, name), 0.0, 1000.0, "")
        _within("trajopt.floor_outlier_distance", self.floor_outlier_distance, 0.01, 1.0, "m")
        _within("trajopt.floor_pitch_prior", self.floor_pitch_prior, 0.0, 10.0, "")
        _within("trajopt.floor_roll_prior", self.floor_roll_prior, 0.0, 10.0, "")
        _within("trajopt.contact_slip_speed", self.contact_slip_speed, 0.0, 100.0, "m/s")
        _within("trajopt.contact_slip_interval", self.contact_slip_interval, 0.01, 1.0, "s")
        _within("trajopt.rest_height", self.rest_height, 0.0, 0.5, "m")
        _within("trajopt.rest_speed", self.rest_speed, 0.0, 10.0, "m/s")
        _within("trajopt.com_interval", self.com_interval, 0.02, 1.0, "s")
        _within("trajopt.segments_per_phase", self.segments_per_phase, 1, 50, "")
        _within("trajopt.segment_phase_seconds", self.segment_phase_seconds, 0.1, 60.0, "s")
        _within("trajopt.min_phase_seconds", self.min_phase_seconds, 0.0, 1.0, "s")
        _within("trajopt.contact_drift", self.contact_drift, 0.0, 1.0, "m")
        for name in ("dynamics_interval", "linear_dynamics_interval", "kinematic_interval", "floor_interval"):
            _within(f"trajopt.{name}", getattr(self, name), 0.0, 1.0, "s")
        _within("trajopt.contact_change_reach", self.contact_change_reach, 0.0, 10.0, "knot intervals")
        _within("trajopt.boundary_frames", self.boundary_frames, 1, 100, "frames")
        _within("trajopt.max_force", self.max_force, 10.0, 1e5, "N")
        _within("trajopt.friction", self.friction, 0.05, 2.0, "")
        _within("trajopt.gravity", self.gravity, 0.0, 30.0, "m/s^2")
        for name in ("weight_com", "weight_orientation", "weight_feet", "weight_duration", "velocity_com",
                     "velocity_orientation", "velocity_feet", "acceleration_com", "acceleration_orientation",
                     "acceleration_feet"):
            _within(f"trajopt.{name}", getattr(self, name), 0.0, 1e4, "")
        _within("trajopt.max_duration_change", self.max_duration_change, 0.0, 1.0, "s")
        _within("trajopt.tolerance", self.tolerance, 1e-10, 1.0, "")
        _within("trajopt.max_iterations", self.max_iterations, 1, 100000, "")
        _within("trajopt.max_seconds", self.max_seconds, 0.1, 1e5, "s")
        if self.reject_departure is not None:
            _within("trajopt.reject_departure", self.reject_departure, 0.01, 10.0, "m")
        _within("trajopt.window_seconds", self.window_seconds, 0.5, 600.0, "s")
        _within("trajopt.window_overlap", self.window_overlap, 0.0, self.window_seconds / 2, "s")
        _within("trajopt.ik_feet_weight", self.ik_feet_weight, 0.01, 1e6, "")
        _within("trajopt.ik_leg_weight", self.ik_leg_weight, 0.0, 1e6, "")
        _within("trajopt.ik_iterations", self.ik_iterations, 1, 200, "")
        _within("trajopt.force_rate", self.force_rate, 0.0, 1e4, "")
        unknown = set(self.constraints) - set(TRAJOPT_CONSTRAINTS)
        if unknown:
            raise InputError(f"trajopt.constraints: unknown {sorted(unknown)}, expected some of {TRAJOPT_CONSTRAINTS}.")
        unknown = set(self.costs) - set(TRAJOPT_COSTS)
        if unknown:
            raise InputError(f"trajopt.costs: unknown {sorted(unknown)}, expected some of {TRAJOPT_COSTS}.")


@dataclass(frozen=True)
class Settings:
    body: BodySettings = field(default_factory=BodySettings)
    camera: CameraSettings = field(default_factory=CameraSettings)
    detect: DetectSettings = field(default_factory=DetectSettings)
    fit: FitSettings = field(default_factory=FitSettings)
    physics: PhysicsSettings = field(default_factory=PhysicsSettings)
    trajopt: TrajoptSettings = field(default_factory=TrajoptSettings)
    online: bool = False  # causal per-frame fit (live use) instead of the whole clip at once
    overlay_width: int = 1280  # px, overlay.mp4 is drawn and encoded at most this wide (0: the video's own width);
    # 0 or 160 .. 7680. 1280 px renders about 4 times faster than 1080p at native size (BENCHMARKS.md, issue 23)

    def check(self) -> "Settings":
        for section in (self.body, self.camera, self.detect, self.fit, self.physics, self.trajopt):
            section.check()
        if self.overlay_width != 0:
            _within("overlay_width", self.overlay_width, 160, 7680, "pixels (or 0: native)")
        if self.physics.method == "trajopt" and self.online:
            raise InputError("physics trajopt optimises the whole clip: it cannot run --online (use physcap).")
        return self

    @property
    def refines_before_physics(self) -> bool:
        """Whether the physics starts from Rempe et al.'s B.4 refinement of the whole clip: trajopt always, PhysCap
        offline unless physics.refine_offline is off."""
        method = self.physics.method
        return method == "trajopt" or (method == "physcap" and self.physics.refine_offline and not self.online)

    def replace(self, section: str | None = None, **values) -> "Settings":
        """A copy with fields changed; `section` names the sub-settings, None the top level."""
        if section is None:
            return dataclasses.replace(self, **values)
        return dataclasses.replace(self, **{section: dataclasses.replace(getattr(self, section), **values)})

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def _check_floor(floor) -> None:
    """Four finite numbers nx,ny,nz,d with a non-zero normal that does not lie along the camera's x axis (the
    world's x axis is the camera's projected onto the floor; a plane containing the camera's y and z axes is
    a wall beside the camera)."""
    numbers = isinstance(floor, (tuple, list)) and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                         for x in floor)
    if not numbers or len(floor) != 4 or not all(math.isfinite(x) for x in floor):
        raise SettingsError(f"camera.floor must be four finite numbers nx,ny,nz,d, got {floor}.")
    norm = math.sqrt(sum(x * x for x in floor[:3]))
    if norm < 1e-9:
        raise SettingsError(f"camera.floor must have a non-zero normal nx,ny,nz, got {floor}.")
    if abs(floor[0]) / norm > math.cos(math.radians(1.0)):
        raise SettingsError(f"camera.floor {floor} is a vertical plane beside the camera (its normal lies along "
                            "the camera's x axis), not a floor.")


def _has_type(value, hint) -> bool:
    """Whether a value read from a settings file has the field's type (int where float is asked is fine)."""
    arms = typing.get_args(hint) if isinstance(hint, types.UnionType) else None
    if arms:
        return any(_has_type(value, arm) for arm in arms)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is int or hint is str or hint is bool:
        return isinstance(value, hint) and (hint is bool or not isinstance(value, bool))
    if typing.get_origin(hint) is tuple:
        items = typing.get_args(hint)
        if not isinstance(value, tuple):
            return False
        if len(items) == 2 and items[1] is Ellipsis:
            return all(_has_type(v, items[0]) for v in value)
        return len(value) == len(items) and all(_has_type(v, t) for v, t in zip(value, items))
    return hint is type(None) and value is None


def _type_name(hint) -> str:
    arms = [a for a in typing.get_args(hint) if a is not type(None)] if isinstance(hint, types.UnionType) else [hint]
    names = {float: "a number", int: "a whole number", bool: "true or false", str: "text"}
    if typing.get_origin(arms[0]) is tuple:
        items = typing.get_args(arms[0])
        return ("a list of " + names.get(items[0], "values") if items[-1] is Ellipsis
                else f"a list of {len(items)} " + names.get(items[0], "values").replace("a ", "") + "s")
    return names.get(arms[0], str(arms[0]))


def _within(name: str, value, low, high, unit: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (low <= value <= high):
        raise InputError(f"{name} = {value} is out of range: expected {low} to {high} {unit}".rstrip() + ".")


def read_toml(path: Path, what: str) -> dict:
    """A user's TOML file (`what`: "settings", "character map") as a dict; InputError naming the file if it is
    missing or not TOML."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what} file.") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML {what} file ({exc}).") from None


def load_settings(path: str | Path | None = None) -> Settings:
    """Defaults, overridden by a TOML file if given."""
    settings = Settings()
    if path is None:
        return settings
    path = Path(path)
    data = read_toml(path, "settings")
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in {f.name for f in dataclasses.fields(Settings)} or not dataclasses.is_dataclass(
                    getattr(settings, key)):
                raise InputError(f"{path}: unknown settings section [{key}].")
            known = {f.name for f in dataclasses.fields(getattr(settings, key))}
            unknown = set(value) - known
            if unknown:
                raise InputError(f"{path}: unknown setting {key}.{sorted(unknown)[0]}.")
            value = {k: tuple(v) if isinstance(v, list) else v for k, v in value.items()}
            hints = typing.get_type_hints(type(getattr(settings, key)))
            for name, item in value.items():
                if not _has_type(item, hints[name]):
                    raise SettingsError(f"{path}: setting {key}.{name} must be {_type_name(hints[name])}, "
                                        f"got {item!r}.")
            settings = settings.replace(key, **value)
        elif key == "online" and not isinstance(value, bool):
            raise SettingsError(f"{path}: setting online must be true or false, got {value!r}.")
        elif key == "online":
            settings = settings.replace(None, online=bool(value))
        elif key == "overlay_width":
            settings = settings.replace(None, overlay_width=value)
        else:
            raise InputError(f"{path}: unknown setting '{key}'.")
    return settings.check()
