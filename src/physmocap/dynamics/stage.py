"""The physics stage: the PhysCap tracker run over a kinematic motion, frame by frame."""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.signal import filtfilt

from ..body import kinematics as kin
from ..body.kinematics import rigid_transform_qpos
from ..body.model import CONTACT_POINTS, BodyModel
from ..body.support import (
    THIGH_POINTS,
    observed_unexplained_frames,
    resting_off_feet,
    resting_points,
    seated_run_frames,
    thighs_level_now,
)
from ..camera import floor_in_camera
from ..config import PhysicsSettings
from ..contacts.flights import held_flights_in_runs
from ..kinematics.stage import KinematicMotion
from ..metrics import GRAVITY
from ..motion import valid_runs
from .balance import BalanceCorrector
from .ballistic import TakeOffPath, take_off_paths
from .floor import FloorRefiner, floor_frame
from .physcap import FrameOutput, PhysCapTracker, frame_share_weights, within_bound
from .planting import FootPlanter, OutputPlanter, plant_held_feet

MAX_FLATTENING = np.radians(20.0)  # a foot tilted more than this with heel and toe predicted down is a wrong label
# or a wrong fit, not a flat foot to correct
REST_SPEED_INTERVAL = 0.1  # s over which a resting sole point's speed is measured (B.4's contact_slip_interval)


@dataclass
class PhysicsMotion:
    """qpos: (T, nq) physically tracked motion; grf: (T, 4, 3) N per contact point (l heel, l toe, r heel,
    r toe), world frame; residual: (T, 6) direct root actuation (force N in the world, torque N m in the pelvis
    frame), both at the frame's instant offline (forces_at_frames), over the interval ending at the frame causally;
    contacts: (T, 4) contacts in use; corrected: (T,) frames whose pose the balance correction changed;
    qp_failures: (T,) integration steps whose QP failed and fell back; seconds: time spent; floor_plane: (4,) the
    refined floor n . x + d = 0 in the motion's world where the physics ended on one (see PhysicsStream), else
    None (the floor is z = 0)."""

    qpos: np.ndarray
    grf: np.ndarray
    residual: np.ndarray
    contacts: np.ndarray
    corrected: np.ndarray
    qp_failures: np.ndarray
    seconds: float
    floor_plane: np.ndarray | None = None
    unexplained: np.ndarray | None = None  # (T,) bool: frames the contact model could not explain, handed back
    # as the kinematic motion (blended in and out: with the whole clip centred on each flagged stretch's edges over
    # settings.unexplained_blend_offline, causally from its first frame on over unexplained_blend); None: not
    # diagnosed

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every field as named arrays for an .npz file (no floor_plane: nan); `from_arrays` rebuilds it."""
        arrays = {f.name: np.asarray(getattr(self, f.name)) for f in dataclasses.fields(self)}
        arrays["floor_plane"] = np.full(4, np.nan) if self.floor_plane is None else np.asarray(self.floor_plane)
        arrays["unexplained"] = np.zeros(0, bool) if self.unexplained is None else np.asarray(self.unexplained, bool)
        return arrays

    @classmethod
    def from_arrays(cls, arrays) -> PhysicsMotion:
        """The motion `to_arrays` gave (a KeyError names a missing array)."""
        values = {f.name: arrays[f.name] for f in dataclasses.fields(cls)}
        values["seconds"] = float(values["seconds"])
        values["floor_plane"] = None if np.isnan(values["floor_plane"]).any() else values["floor_plane"]
        values["unexplained"] = None if len(values["unexplained"]) == 0 else values["unexplained"]
        return cls(**values)


def refined_gains(settings: PhysicsSettings) -> PhysicsSettings:
    """The settings with the joint gains for B.4 input (kp_joint_refined, kd_joint_refined where set): the per-frame
    fits' gains are soft against their noise, and lag a smooth target (docs/decisions/physcap-tracking.md)."""
    return dataclasses.replace(settings, kp_joint=settings.kp_joint if settings.kp_joint_refined is None
                               else settings.kp_joint_refined,
                               kd_joint=settings.kd_joint if settings.kd_joint_refined is None
                               else settings.kd_joint_refined)


class PhysicsStream:
    """The physics stage one frame at a time (live capture, and `run_physcap` frame by frame): estimates the
    kinematic velocities causally, lifts targets whose feet sink out of the floor, corrects balance, and tracks.
    With refine_floor (an online fit whose floor was estimated, not given) the floor is refined as frames arrive
    and the character runs on the refined floor; poses and forces come back in the kinematic world
    (`onto_refined_floor` moves both onto the final floor); floor_trusted False (a warm-up floor levelled with the
    posture because its feet's plane leant from it) refines only its height. refined_input, resting_labelled,
    whole_clip: see `run_physcap`."""

    def __init__(self, body: BodyModel, settings: PhysicsSettings, fps: float, refine_floor: bool = False,
                 refined_input: bool = False, resting_labelled: bool = False, whole_clip: bool = False,
                 floor_trusted: bool = True):
        self.body, self.settings, self.fps = body, settings, fps
        self.floor = (FloorRefiner(body, fps, settings.floor_refit_interval, np.radians(settings.floor_tilt_rate),
                                   settings.floor_lift_rate, settings.floor_refine_after, keep_tilt=not floor_trusted)
                      if refine_floor and settings.floor_refit_interval is not None else None)
        # Held contacts are settled onto B.4's feet; targets this stream lifts itself (online fits) are not: there
        # it doubled the held contacts' p95 slide on the estimated floor (docs/decisions/physics-default.md).
        self.tracker = PhysCapTracker(body, refined_gains(settings) if refined_input else settings, fps,
                                      settle_contacts=refined_input)
        self.target = body.rest_qpos.copy()  # the last frame's target (nq,): its kinematic pose after 4.3.1
        # share of the newest backward difference in the smoothed velocity (1: no smoothing)
        smoothing = settings.velocity_smoothing
        self._new_share = 1.0 - np.exp(-1.0 / (fps * smoothing)) if smoothing else 1.0
        # Kinematics refined by Rempe's B.4 (refined_input) already rest their feet on the floor: lifting and
        # flattening them again only raised the feet (docs/decisions/physics-default.md); nor are they planted.
        self._fit_feet = settings.foot_lock != "never" and not refined_input  # a fit's feet on the floor, B.4's not
        self._whole_clip = whole_clip
        self.tracker.split_forces = True  # FrameOutput.shares: the forces at the frames' instants (forces_at_frames)
        self._lift_share = (1.0 - np.exp(-1.0 / (fps * settings.target_lift_time))
                            if settings.target_lift_time is not None and self._fit_feet else 0.0)
        model = self.tracker.model
        feet = [model.body(f"{side}_foot").id for side in ("left", "right")]
        self._feet = [(foot, model.body_parentid[foot], model.jnt_qposadr[model.body_jntadr[foot]]) for foot in feet]
        self._turn, self._quat = np.zeros(4), np.zeros(4)
        self._root_frames = max(1, round(settings.stationary_speed_interval * fps)) + 1  # the interval's ends
        self._weight = body.mass * GRAVITY
        self._unexplained_share = 1.0 - np.exp(-1.0 / (fps * settings.unexplained_time))
        self._blend_rate = 1.0 / max(fps * settings.unexplained_blend, 1.0)
        self._blend_step = np.zeros(body.nv)
        self._deviation_data = mujoco.MjData(model)
        self._resting_sites = np.array([model.site(body.point_names[i]).id for i in resting_points(body.point_names)])
        self._thigh_sites = np.array([model.site(name).id for name in THIGH_POINTS])
        self._frames_to_sit = seated_run_frames(fps)  # this many frames with level thighs: seated (seated_frames)
        self._drop_keep = (math.exp(-1.0 / (fps * settings.start_drop_time))
                           if settings.start_drop_time is not None else 0.0)
        self._rests = (settings.rest_height is not None and settings.foot_lock == "auto" and not refined_input
                       and not resting_labelled)
        self.restart()

    def restart(self) -> None:
        """Sets the state of one track afresh (the refined floor stays): at the start, and after frames the contact
        model cannot explain (`_not_tracked`, run_physcap's frames known unexplainable), so that the character
        starts again from the next frame's target, as at the clip's start."""
        body, settings, fps, model = self.body, self.settings, self.fps, self.tracker.model
        # 4.3.1's share of the lean corrected per frame, from a time constant: per frame, the correction grew six
        # times faster in seconds at 60 fps than at 10 (docs/decisions/physics-balance.md)
        self.balance = BalanceCorrector(body, 1.0 - math.exp(-1.0 / (fps * settings.correction_time)))
        self._previous: np.ndarray | None = None  # last kinematic pose
        self._velocity, self._frames = np.zeros(body.nv), 0  # the last smoothed kinematic velocity; frames pushed
        # The targets' lift out of the floor (their lowest predicted contact point's depth, smoothed), how flat each
        # foot is turned (0 .. 1, smoothed), and the share of a new frame's value taken in (settings.target_lift_time)
        self._lift, self._flatness = 0.0, np.zeros(2)
        # kinematic root positions of the last stationary_speed_interval, oldest first (the stationary gate)
        self._roots: deque[np.ndarray] = deque(maxlen=self._root_frames)
        # The diagnosis (settings.unexplained_*): the unexplained root force, averaged causally over
        # unexplained_time, and the kinematic motion's share in the output (0: physics, 1: kinematic)
        self._unexplained = np.zeros(3)
        self._kinematic_share = 0.0
        self._level_frames = 0  # frames up to the last one whose target's thighs were level (support.thighs_level)
        # The start's drop onto the floor (m; None before the first frame), its share kept a frame (start_drop_time)
        self._drop: float | None = None
        # Online fits' held feet are planted where the character holds them, and the output's stand still,
        # causally (with the whole clip, B.4 planted the target's and run_physcap plants the output's)
        self.planter = (FootPlanter(model, fps, settings.plant_time, settings.release_distance)
                        if self._fit_feet and settings.plant_time is not None else None)
        self.output_planter = (OutputPlanter(model, fps, settings.plant_reach)
                               if self._fit_feet and settings.plant_reach and not self._whole_clip else None)
        self._held = np.zeros(4, bool)  # the contacts the character held at the end of the last frame
        # Online fits' sole points resting on the floor are contacts though not predicted (as B.4 adds offline);
        # the window holds their positions over REST_SPEED_INTERVAL, oldest first.
        self._resting_window: deque[np.ndarray] | None = (
            deque(maxlen=max(1, round(REST_SPEED_INTERVAL * fps)) + 1) if self._rests else None)

    def resume(self, q_kin: np.ndarray) -> bool:
        """The person seen again, in pose q_kin (nq,), after frames without one: causally those frames held the
        fit's extrapolation, and the person can reappear a metre from it (intel online: the character pulled after
        such a jump at the force bound). If the character's bodies lie farther from q_kin's than stray_distance on
        average, the character starts afresh (restart), as at the clip's start. Returns whether it did. (Offline,
        the whole clip's fit bridges such gaps with data on both sides.)"""
        if not self._frames:
            return False
        if self.floor is not None:
            q_kin = self.floor.to_physics(q_kin)
        target = self.tracker.target_data  # the tracker's scratch for target kinematics, next set in track()
        target.qpos[:] = q_kin
        mujoco.mj_kinematics(self.tracker.model, target)
        if self._deviation() <= self.settings.stray_distance:
            return False
        self.restart()
        return True

    @property
    def floor_plane(self) -> np.ndarray | None:
        """The refined floor n . x + d = 0 in the kinematic world, or None when not refining."""
        return None if self.floor is None else self.floor.plane

    def push(self, q_kin: np.ndarray, contacts: np.ndarray, stationary: bool,
             velocity_kin: np.ndarray | None = None,
             take_off: TakeOffPath | None = None) -> tuple[np.ndarray, FrameOutput, bool]:
        """One frame's kinematic pose (nq,), contacts (4,) and stationary flag -> tracked pose, forces, and
        whether the balance correction changed the target (a pose whose centre of mass is below the floor: not
        tracked, `_not_tracked`). velocity_kin (nv,): the pose's velocity where the caller holds the whole clip
        (zero_phase_velocities; no floor refined, no targets planted), in place of the causally smoothed one; take_off:
        where the caller holds the whole clip, the path of an interval that ends at a flight's first frame
        (PhysCapTracker.track)."""
        if self.floor is not None:
            self.floor.push(q_kin, contacts)
            q_kin = self.floor.to_physics(q_kin)
        if self._centre_of_mass_height(q_kin) < 0.0:
            return self._not_tracked(q_kin)
        if self._resting_window is not None:
            contacts = contacts | self._resting(q_kin)
        if self._lift_share:
            q_kin = self._target_on_floor(q_kin, contacts)
        drop_before = self._drop or 0.0
        if self._drop_keep:
            q_kin = self._start_on_floor(q_kin)
        released = None
        if self.planter is not None and self._previous is not None:
            q_kin, released = self._plant_feet(q_kin, contacts)
        # Backward differences (as kinematic_derivatives), the velocity smoothed causally from the second one on
        # (settings.velocity_smoothing), or given smoothed without lag (velocity_kin) plus the start drop's own;
        # no acceleration before the third frame.
        velocity, acceleration = np.zeros(self.body.nv), np.zeros(self.body.nv)
        if self._previous is None:
            self.tracker.reset(q_kin, velocity)
        else:
            if velocity_kin is None:
                mujoco.mj_differentiatePos(self.tracker.model, velocity, 1.0 / self.fps, self._previous, q_kin)
            else:
                velocity[:] = velocity_kin
                velocity[2] -= ((self._drop or 0.0) - drop_before) * self.fps
            if self._frames == 1:  # the first velocity known: the character, started at rest, takes it
                self.tracker.qvel[:] = velocity
            if self._frames >= 2:
                if velocity_kin is None:
                    velocity = self._new_share * velocity + (1.0 - self._new_share) * self._velocity
                acceleration = (velocity - self._velocity) * self.fps
        self._previous, self._velocity = q_kin, velocity
        self._frames += 1
        target, corrected = q_kin, False
        self._roots.append(q_kin[:3].copy())
        if stationary and self.settings.stationary_max_speed is not None:
            stationary = self.root_speed() < self.settings.stationary_max_speed
        if self.settings.balance_correction:
            target, corrected = self.balance.correct(q_kin, stationary, contacts)
        self.target = target
        frame = self.tracker.track(target, velocity, acceleration, contacts, released, take_off)
        self._held = frame.active
        pose = self._diagnose(frame, target, velocity)
        if self.output_planter is not None:
            pose = self.output_planter.plant(pose, frame.active, bool(frame.unexplained_flag))
        if self.floor is None:
            return pose, frame, corrected
        to_kinematic = self.floor.wrench_to_kinematic
        frame.contact_forces, frame.residual = to_kinematic(frame.contact_forces, frame.residual)
        if frame.shares is not None:
            frame.shares = (to_kinematic(*frame.shares[0]), to_kinematic(*frame.shares[1]))
        return self.floor.to_kinematic(pose), frame, corrected

    def _centre_of_mass_height(self, q: np.ndarray) -> float:
        """m: the height of pose q's (nq,) centre of mass above the floor (z = 0 of the physics' world)."""
        data = self._deviation_data
        data.qpos[:] = q
        mujoco.mj_kinematics(self.tracker.model, data)
        mujoco.mj_comPos(self.tracker.model, data)
        return float(data.subtree_com[0, 2])

    def _not_tracked(self, q_kin: np.ndarray) -> tuple[np.ndarray, FrameOutput, bool]:
        """A frame whose target's centre of mass lies below the floor (a detection or floor error: a person leaving
        the view) is one no contact force explains (body.support.unexplained_frames, which the offline path finds
        before tracking): it keeps the target, flagged, with no force claimed, and the character starts afresh at
        the next frame, as at the clip's start (restart)."""
        if self._frames:  # a track is under way (restart, about 1 ms, is not repeated on every such frame)
            self.restart()
        self.target = q_kin
        frame = FrameOutput(contact_forces=np.zeros((4, 3)), residual=np.zeros(6), active=np.zeros(4, bool),
                            qp_failures=0, unexplained_flag=True, tracked=False)
        pose = q_kin.copy()
        return (pose if self.floor is None else self.floor.to_kinematic(pose)), frame, False

    def _plant_feet(self, q_kin: np.ndarray, contacts: np.ndarray) -> tuple[np.ndarray, list[bool]]:
        """q_kin (nq,) with the contact points the character held in the last frame, still predicted (contacts
        (4,)) and not released, moved onto their planted points (FootPlanter), and the frame's released contacts.
        Those are judged against where the target's points lay (the fit's moved by the planter's shifts): judged
        on the fit's own, planted points that lagged the fit's were let go and caught up at once more often than
        without planting (docs/decisions/physics-online-feet.md). None is held while the balance correction
        turns the body about its feet: planted as well, the feet it had turned misled its support test, and the
        correction tipped a body leaning on its toes over backwards."""
        assert self.planter is not None
        fitted = self.planter.contact_points(q_kin)
        released, character = self.tracker.release_contacts(self.planter.shifted(fitted), contacts)
        correcting = self.balance.tilt > 0.0 or self.balance.straighten > 0.0
        held = [bool(self._held[j] and contacts[j]) and not released[j] and not correcting for j in range(4)]
        return self.planter.plant(q_kin, fitted, character, held), released

    def _diagnose(self, frame: FrameOutput, target: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Bounds the frame's forces (settings.max_force) and judges whether the contact model explains the
        frame: the upward root force the kinematic motion needs and no contact on the floor can give
        (FrameOutput.unexplained[2]: something else holds the body up) averaged over unexplained_time above
        unexplained_force, the target resting on a knee, an elbow or the seat (body.support.resting_off_feet) or
        seated (its thighs level for SEATED_TIME up to this frame: body.support.seated_frames, causally), a
        diverged step or failed QP, a force over the bound, or the character farther than stray_distance from its
        target. Sets frame.unexplained_flag and
        returns the pose to hand out (nq,): the character's, blended towards the frame's kinematic target over
        unexplained_blend while frames are flagged; a character fully handed over restarts from the target (with
        the whole clip too: there centred_hand_back then blends the output over unexplained_blend_offline)."""
        s = self.settings
        bound = s.max_force * self._weight
        out_of_bounds = False
        for forces in (frame.contact_forces, frame.residual[:3], frame.residual[3:]):  # torque: bound x 1 m
            total = forces.sum(axis=0) if forces.ndim == 2 else forces
            size = math.sqrt(total.dot(total))  # np.linalg.norm's own sum, without its checks
            if not math.isfinite(size):  # a non-finite force (an overflowing sum too, which the bound would zero)
                forces[:] = 0.0
                out_of_bounds = True
            elif size > bound:
                forces *= bound / size
                out_of_bounds = True
        finite = all(map(math.isfinite, frame.unexplained.tolist()))
        unexplained = frame.unexplained[:3] if finite else np.zeros(3)
        self._unexplained += self._unexplained_share * (unexplained - self._unexplained)
        target_points = self.tracker.target_data.site_xpos
        level = thighs_level_now(*target_points[self._thigh_sites].tolist())
        self._level_frames = self._level_frames + 1 if level else 0
        flagged = (out_of_bounds or frame.diverged or frame.qp_failures > 0
                   or (s.unexplained_force is not None
                       and self._unexplained[2] > s.unexplained_force * self._weight)
                   or bool(resting_off_feet(target_points[self._resting_sites, 2]))
                   or self._level_frames >= self._frames_to_sit
                   or self._deviation() > s.stray_distance)
        frame.unexplained_flag = flagged
        # An explained frame reports the forces its motion needed (PhysCapTracker.track): what the contact
        # constraints did (a floor holding up a body its PD pulls down) is then the floor's force where an
        # admissible one gives it, not root residual (docs/decisions/physics-residual-attribution.md). Flagged
        # frames keep the load the contact model cannot explain on the residual (a NaN fit fails the bound: the
        # bounded fit above stays), and their forces split between frames by the steps' weights alone.
        if not flagged and frame.motion_forces is not None and within_bound(*frame.motion_forces, bound):
            frame.contact_forces, frame.residual = frame.motion_forces
        else:
            frame.shares = None
        self._kinematic_share = min(1.0, self._kinematic_share + self._blend_rate) if flagged else \
            max(0.0, self._kinematic_share - self._blend_rate)
        if self._kinematic_share >= 1.0:
            self.tracker.reset(target, velocity)
            return target.copy()
        pose = self.tracker.qpos.copy()
        if self._kinematic_share > 0.0:
            mujoco.mj_differentiatePos(self.tracker.model, self._blend_step, 1.0, pose, target)
            mujoco.mj_integratePos(self.tracker.model, pose, self._blend_step, self._kinematic_share)
        return pose

    def _deviation(self) -> float:
        """m: mean distance between the character's bodies and the target's whose kinematics lie in
        tracker.target_data (after a frame, PhysCapTracker.kinematic_misfit left the frame target's there)."""
        data = self._deviation_data
        data.qpos[:] = self.tracker.qpos
        mujoco.mj_kinematics(self.tracker.model, data)
        offset = data.xpos[1:] - self.tracker.target_data.xpos[1:]
        distances = np.sqrt((offset * offset).sum(axis=1))
        return float(distances.sum()) / len(distances)  # np.mean's own sum and division, without its overhead

    def _target_on_floor(self, q_kin: np.ndarray, contacts: np.ndarray) -> np.ndarray:
        """q_kin with each foot whose heel and toe are both predicted in contact turned flat (about the ankle, by
        at most MAX_FLATTENING), then raised along the floor normal by the depth of its lowest predicted contact
        point under the floor; both smoothed with settings.target_lift_time. Only contacts that eq. (5) would
        accept (within contact_height of the floor) count; in flight the lift is held. A copy."""
        # The tracker's scratch data for target kinematics (it is next used in track(), after this frame's lift).
        target, data, model = q_kin.copy(), self.tracker.target_data, self.tracker.model
        data.qpos[:] = target
        mujoco.mj_kinematics(model, data)
        near = contacts & (data.site_xpos[self.tracker.sites, 2] < self.settings.contact_height)
        turned = False
        if self.settings.flatten_feet:
            for side, (body, parent, address) in enumerate(self._feet):
                both_down = bool(near[2 * side] and near[2 * side + 1])
                if not both_down and self._flatness[side] < 1e-6:
                    self._flatness[side] = 0.0
                    continue
                axes = data.xmat[body].tolist()  # row-major 3 x 3: the heel -> toe axis is column 0
                x, y, z = axes[0], axes[3], axes[6]
                length = math.hypot(x, y)
                if length < 1e-6:  # a foot pointing straight up or down: no level direction, and no flat foot
                    continue
                tilt = math.atan2(z, length)  # toes up > 0; turning by it about (-y, x, 0) / length levels the foot
                flat = both_down and abs(tilt) < MAX_FLATTENING
                self._flatness[side] += self._lift_share * (float(flat) - self._flatness[side])
                # The turn about that world axis a, in the ankle's (parent body's) frame: R_parent' a.
                r = data.xmat[parent].tolist()
                ax, ay = -y / length, x / length
                half = 0.5 * self._flatness[side] * tilt
                sine = math.sin(half)
                self._turn[:] = (math.cos(half), sine * (r[0] * ax + r[3] * ay), sine * (r[1] * ax + r[4] * ay),
                                 sine * (r[2] * ax + r[5] * ay))
                mujoco.mju_mulQuat(self._quat, self._turn, target[address:address + 4])
                target[address:address + 4] = self._quat
                turned = True
        if turned:  # the sites' heights after the turn
            data.qpos[:] = target
            mujoco.mj_kinematics(model, data)
        if near.any():
            depth = -data.site_xpos[self.tracker.sites[near], 2].min()
            self._lift += self._lift_share * (max(depth, 0.0) - self._lift)
        target[2] += self._lift
        return target

    def _resting(self, q_kin: np.ndarray) -> np.ndarray:
        """(4,) the target's sole points that rest on the floor (z = 0): below settings.rest_height (under the
        floor too) and slower than settings.slide_speed, eq. (9)'s slip of a held contact, over the last
        REST_SPEED_INTERVAL (causal). A contact network misses contacts on footage unlike its training (on one
        standing video it labelled one heel or none for seconds), and the character then had fewer supports than
        the person stood on: the balance correction leant it off the feet it saw."""
        assert self._resting_window is not None and self.settings.rest_height is not None
        data = self.tracker.target_data  # scratch: _target_on_floor computes its own kinematics next
        data.qpos[:] = q_kin
        mujoco.mj_kinematics(self.tracker.model, data)
        points = data.site_xpos[self.tracker.sites].copy()
        window = self._resting_window
        window.append(points)
        if len(window) < 2:
            return np.zeros(len(points), bool)
        travel = points[:, :2] - window[0][:, :2]
        speed = np.sqrt((travel * travel).sum(axis=1)) * self.fps / (len(window) - 1)
        return (points[:, 2] < self.settings.rest_height) & (speed < self.settings.slide_speed)

    def _start_on_floor(self, q_kin: np.ndarray) -> np.ndarray:
        """q_kin lowered by the drop: on the first frame, the height of the target's lowest sole point where that
        lies above the floor but within contact_height (a fit whose first frames hover, not a start in flight: the
        character would fall onto the floor and land hard); afterwards never more than the lowest point's height
        (the target coming down itself), fading with start_drop_time (a target that never comes down). A copy."""
        if self._drop == 0.0:
            return q_kin
        data, model = self.tracker.target_data, self.tracker.model
        data.qpos[:] = q_kin
        mujoco.mj_kinematics(model, data)
        lowest = float(data.site_xpos[self.tracker.sites, 2].min())
        if self._drop is None:
            self._drop = lowest if 0.0 < lowest < self.settings.contact_height else 0.0
        else:
            self._drop = min(self._drop * self._drop_keep, max(lowest, 0.0))
            if self._drop < 1e-4:  # m: gone; the next frames skip the kinematics
                self._drop = 0.0
        target = q_kin.copy()
        target[2] -= self._drop
        return target

    def root_speed(self) -> float:
        """m/s: the kinematic root's displacement over the last stationary_speed_interval divided by that
        interval (in the first frames, the displacement so far over the whole interval: the flag is believed
        until the root has moved)."""
        interval = (self._root_frames - 1) / self.fps
        displacement = self._roots[-1] - self._roots[0]
        return math.sqrt(displacement.dot(displacement)) / interval  # np.linalg.norm's own sum, without its layer


def kinematic_derivatives(body: BodyModel, qpos: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Causal (backward) finite differences on the manifold: velocities and accelerations (T, nv)."""
    velocity = np.zeros((len(qpos), body.nv))
    velocity[1:] = kin.difference(body, qpos[:-1], qpos[1:]) * fps
    acceleration = np.zeros_like(velocity)
    acceleration[2:] = np.diff(velocity[1:], axis=0) * fps
    return velocity, acceleration


def run_physcap(body: BodyModel, qpos_kin: np.ndarray, fps: float, contacts: np.ndarray, stationary: np.ndarray,
                settings: PhysicsSettings, progress=None, refine_floor: bool = False,
                valid: np.ndarray | None = None, refined_input: bool = False,
                resting_labelled: bool = False, whole_clip: bool = False, floor_trusted: bool = True) -> PhysicsMotion:
    """Track the kinematic motion (T, nq) with the physics character; contacts (T, 4) and stationary (T,)
    come from the contact stage. Causal: frame t's motion uses frames up to t only, unless whole_clip; its forces, once
    every frame is tracked, are read at its instant from the intervals either side of it (forces_at_frames): the
    interval before it alone, which a live stream hands out as it goes, lagged the character's motion and was
    further from the true vertical force than a constant body weight (docs/decisions/physics-force-timing.md).
    refine_floor, floor_trusted: see PhysicsStream.
    valid: (T,) frames with a detected person (default all); the character starts at the first (whole_clip: at the
    first observed step, _first_frame), and the frames before it keep the kinematic pose without forces, flagged
    where they show a person (a whole-clip fit extrapolates them without data, and a character started there can
    begin metres off); frames
    after it without a person are tracked through but carry no contacts, contact forces or residual (their flags
    stay).
    refined_input: the kinematics come from Rempe's B.4 refinement (offline, PhysicsSettings.refine_offline), whose
    feet already rest on the floor: targets are not lifted or flattened (target_lift_time, flatten_feet are for
    fits whose feet sink); implies whole_clip.
    resting_labelled: the contacts already hold the points resting on the floor (a capture's contacts in use, which
    retargeting carries over), so none are added (rest_height; B.4's refinement implies it).
    whole_clip: the caller holds the whole clip (as B.4 input and a retargeted capture do), so flights of its
    labels that the motion does not fall through are held, and the frames the contact model cannot explain are
    known before tracking (offline_unexplainable: kept kinematic, no force claimed, the character restarted after
    them); the hand-back to the kinematic motion is centred on each flagged stretch (centred_hand_back), and the
    held feet are planted on their spots over the whole clip (planting.plant_held_feet, settings.plant_reach), not
    by the causal OutputPlanter; and each interval that ends at a flight's first frame pushes onto the flight's
    parabola (ballistic.take_off_paths) instead of aiming at the chord (without a refined floor)."""
    start = time.perf_counter()
    T = len(qpos_kin)
    whole_clip = whole_clip or refined_input
    unexplainable = np.zeros(T, bool)
    if whole_clip:
        contacts, unexplainable = offline_unexplainable(body, qpos_kin, fps, contacts, valid)
    unexplained = np.zeros(T, bool)
    out = PhysicsMotion(qpos_kin.copy(), np.zeros((T, 4, 3)), np.zeros((T, 6)), np.zeros((T, 4), bool),
                        np.zeros(T, bool), np.zeros(T, int), 0.0, unexplained=unexplained)
    # The character's own poses and the frames' targets, for centred_hand_back
    recorded = (qpos_kin.copy(), qpos_kin.copy()) if whole_clip and not refine_floor else None
    stream = PhysicsStream(body, settings, fps, refine_floor, refined_input, resting_labelled, whole_clip,
                           floor_trusted)
    shares: list = [None] * T  # each tracked frame's FrameOutput.shares
    seen = np.ones(T, bool) if valid is None else np.asarray(valid, bool)
    usable = seen & ~unexplainable  # the frames the character may track
    velocities = (zero_phase_velocities(body, qpos_kin, fps, settings.velocity_smoothing, usable)
                  if refined_input and not refine_floor else None)
    flights = whole_clip and not refine_floor and bool((usable & ~contacts.any(axis=1)).any())
    take_offs = (take_off_paths(kin.center_of_mass(body, kin.forward_kinematics(body, qpos_kin))[:, 2], contacts,
                                usable, fps, GRAVITY, settings.max_force)
                 if flights else {})  # a forward-kinematics pass, spared where the labels hold no flight
    tracked = _track(stream, qpos_kin, contacts, stationary, valid, unexplainable, whole_clip, out, recorded,
                     shares, progress, velocities, take_offs)
    if recorded is not None:
        out.qpos = centred_hand_back(stream.tracker.model, *recorded, unexplained, fps,
                                     settings.unexplained_blend_offline)
    gone = ~seen
    out.grf, out.residual, out.contacts = written_forces(out.grf, out.residual, out.contacts, tracked & ~gone, gone,
                                                         shares, stream.tracker.substeps)
    if whole_clip and settings.plant_reach:
        # the feet stand where the poses the character tracked (the balance correction's included) put them
        tracked_targets = qpos_kin if recorded is None else recorded[1]
        out.qpos = plant_held_feet(body, out.qpos, out.contacts, fps, settings.plant_reach, gone | unexplained,
                                   tracked_targets)
    out.seconds = time.perf_counter() - start
    out.floor_plane = stream.floor_plane
    return out


def zero_phase_velocities(body: BodyModel, qpos: np.ndarray, fps: float, smoothing: float,
                          tracked: np.ndarray) -> np.ndarray:
    """(T, nv): the backward differences of qpos (T, nq) on the manifold, smoothed forward then backward by an
    exponential filter within each run of tracked frames (T,) bool, the character's track between restarts: the
    causal smoothing's noise reduction (smoothing, s; 0: none) without its lag, which took the physics further from
    the truth than its input (docs/decisions/physcap-tracking.md). Each pass's time constant is smoothing *
    sqrt(sqrt(2) - 1), so that the two passes cut at about the one pass's -3 dB frequency."""
    velocity, _ = kinematic_derivatives(body, qpos, fps)
    if not smoothing:
        return velocity
    share = 1.0 - math.exp(-1.0 / (fps * smoothing * math.sqrt(math.sqrt(2.0) - 1.0)))
    for start, stop in valid_runs(tracked):
        # a run's first frame has no backward difference within it; each pass starts in its first one's steady state
        if stop - start > 2:
            velocity[start + 1:stop] = filtfilt([share], [1.0, share - 1.0], velocity[start + 1:stop], axis=0,
                                                padtype=None)
    return velocity


def _track(stream: PhysicsStream, qpos_kin: np.ndarray, contacts: np.ndarray, stationary: np.ndarray,
           valid: np.ndarray | None, unexplainable: np.ndarray, observed_step: bool, out: PhysicsMotion,
           recorded, shares: list, progress, velocities: np.ndarray | None = None,
           take_offs: dict[int, TakeOffPath] | None = None) -> np.ndarray:
    """Runs the character (stream) over the frames into out, recorded and shares (as run_physcap's), from
    _first_frame on; returns the frames the character tracked (T,) bool (a frame the stream kept untracked
    claims no force).
    Frames known unexplainable (T,) keep the kinematic pose with no force claimed, flagged; after them the
    character starts afresh (PhysicsStream.restart), as at the clip's start, at the first frame whose step to the
    next is observed (both valid, both explainable) and that begins a run of such frames at least
    settings.unexplained_time long, which the diagnosis can judge (the frames waiting for it are kept and flagged
    too: a character restarted for two frames between two such stretches claimed 3.4 body weights). Causally
    (not observed_step), a person seen again after frames without one may restart it (PhysicsStream.resume)."""
    T = len(qpos_kin)
    seen = np.ones(T, bool) if valid is None else np.asarray(valid, bool)
    eligible = seen & ~unexplainable
    runway = np.zeros(T, int)  # eligible frames from each frame on, itself included
    for start, stop in valid_runs(eligible):
        runway[start:stop] = np.arange(stop - start, 0, -1)
    shortest = max(2, math.ceil(stream.settings.unexplained_time * stream.fps - 1e-9))
    first = _first_frame(valid, observed_step)
    flagged = out.unexplained
    assert flagged is not None, "run_physcap's motion carries its flags"
    flagged[:first] = seen[:first]  # a person shown before the first observed step: kept, no force claimed
    waiting = False  # after an unexplainable stretch, for an observed step
    tracked = np.zeros(T, bool)
    for t in range(first, T):
        if unexplainable[t]:
            waiting, flagged[t] = True, True
        elif waiting and runway[t] < shortest:
            flagged[t] = True
        else:
            if waiting:
                stream.restart()
                waiting = False
            elif not observed_step and t > first and seen[t] and not seen[t - 1]:
                stream.resume(qpos_kin[t])
            out.qpos[t], frame, out.corrected[t] = stream.push(
                qpos_kin[t], contacts[t], bool(stationary[t]), None if velocities is None else velocities[t],
                take_offs.get(t) if take_offs and t > first and tracked[t - 1] else None)
            tracked[t] = frame.tracked
            if recorded is not None:
                recorded[0][t], recorded[1][t] = stream.tracker.qpos, stream.target
            out.grf[t], out.residual[t], out.contacts[t], out.qp_failures[t], flagged[t] = (
                frame.contact_forces, frame.residual, frame.active, frame.qp_failures, frame.unexplained_flag)
            shares[t] = frame.shares
        if progress:
            progress(t + 1, T)
    return tracked


def written_forces(grf: np.ndarray, residual: np.ndarray, contacts: np.ndarray, claimed: np.ndarray,
                   gone: np.ndarray, shares: list, substeps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact forces (T, 4, 3) N, root residual (T, 6) and contacts in use (T, 4) that a tracked motion writes,
    from each frame's (PhysicsStream.push) and their shares: frames without a person (gone, (T,) bool) were tracked
    through but claim no contact and no force; the others' forces are read at their instants (forces_at_frames)
    where the frame and its neighbour claim them (claimed, (T,) bool). New arrays."""
    grf, residual, contacts = grf.copy(), residual.copy(), contacts.copy()
    grf[gone], residual[gone], contacts[gone] = 0.0, 0.0, False
    grf, residual = forces_at_frames(grf, residual, claimed, contacts.any(axis=1), shares, substeps)
    return grf, residual, contacts


def forces_at_frames(grf: np.ndarray, residual: np.ndarray, claimed: np.ndarray, supported: np.ndarray,
                     shares: list, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """The forces at each frame's instant, from the character's forces over the interval that ends at
    each frame (PhysCapTracker.track averages its `substeps` steps): what m (x'' + g) of the character's own path
    reads at the frame by central differences two frames apart, (v[t+1] - v[t-1]) / 2 dt with the velocities
    themselves centred, v[t] = (x[t+1] - x[t-1]) / 2 dt.
    - First the force that bends the path at each frame (x[t+1] - 2 x[t] + x[t-1]): its share of the interval
      before it plus its share of the one after it (FrameOutput.shares; where the tracker did not split an
      interval's forces, a flagged frame's, by the steps' weights: (n + 1) / 2n to the start frame).
    - Then 1/4, 1/2, 1/4 of those bends at the frame before, the frame and the frame after, where the neighbour
      is supported as the frame is or is not (supported, (T,) bool: a contact in use), so that a landing's force
      does not spread into the flight before it; a missing or other neighbour's bend counts as the frame's own,
      so that each frame's bend is shared out whole.
    The mean of the two intervals' forces, read with the character's own velocities at the frames, lagged the
    motion by a third to half a frame: the character takes up each frame's change of the target's chord just
    after the frame (docs/decisions/physics-force-timing.md). Frames where the frame and the next both claim
    forces (claimed, (T,) bool) are read so; the others keep their own interval's. A point that touches down in
    the interval after a frame carries its share of that interval's force at the frame, so that no impulse is
    lost. grf: (T, 4, 3) N; residual: (T, 6) (force N, torque N m); returns both, new arrays."""
    weights = frame_share_weights(substeps)  # (start frame's, end frame's)

    def share(t: int, k: int) -> tuple[np.ndarray, np.ndarray]:  # k: 0 the start frame's share, 1 the end's
        return shares[t][k] if shares[t] is not None else (weights[k] * grf[t], weights[k] * residual[t])

    bending: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for t in np.flatnonzero(claimed[:-1] & claimed[1:]).tolist():
        (end_forces, end_residual), (start_forces, start_residual) = share(t, 1), share(t + 1, 0)
        bending[t] = (end_forces + start_forces, end_residual + start_residual)
    at_grf, at_residual = grf.copy(), residual.copy()
    for t, own in bending.items():
        before, after = [bending[u] if u in bending and supported[u] == supported[t] else own for u in (t - 1, t + 1)]
        at_grf[t] = 0.25 * before[0] + 0.5 * own[0] + 0.25 * after[0]
        at_residual[t] = 0.25 * before[1] + 0.5 * own[1] + 0.25 * after[1]
    return at_grf, at_residual


def _first_frame(valid: np.ndarray | None, observed_step: bool) -> int:
    """The frame the character starts at: the first valid frame (T,); with observed_step (the whole clip known),
    the first of two valid frames in a row, whose step gives the character an observed velocity (a lone valid
    frame's step to the next reaches a pose the fit extrapolated without a person). 0 with all frames valid
    (None) or none."""
    if valid is None or not np.any(valid):
        return 0
    valid = np.asarray(valid, bool)
    if observed_step:
        pairs = np.flatnonzero(valid[:-1] & valid[1:])
        if len(pairs):
            return int(pairs[0])
    return int(np.argmax(valid))


def centred_hand_back(model: mujoco.MjModel, tracked: np.ndarray, targets: np.ndarray, flagged: np.ndarray,
                      fps: float, blend: float) -> np.ndarray:
    """(T, nq) poses: the character's own (tracked, (T, nq)) handed over to the frames' targets (T, nq) on the
    flagged frames (T,) and blended towards them over `blend` seconds on either side of each flagged stretch.
    Offline only: the whole clip known, the hand-over is done when the unexplained motion begins, where the causal
    stream only starts it (most of the root error inside the diagnosis' box came from the frames before the flag
    rose: docs/decisions/physics-limits.md). Frames farther than `blend` from every flagged frame keep the
    character's pose; blend 0: only the flagged frames are handed over."""
    out = tracked.copy()
    index = np.flatnonzero(flagged)
    if not len(index):
        return out
    frames = np.arange(len(out))
    after = np.minimum(np.searchsorted(index, frames), len(index) - 1)  # the nearest flagged frame on each side
    before = np.maximum(after - 1, 0)
    seconds = np.minimum(np.abs(index[after] - frames), np.abs(frames - index[before])) / fps
    share = np.clip(1.0 - seconds / blend, 0.0, 1.0) if blend > 0.0 else (seconds == 0.0).astype(float)
    step = np.zeros(model.nv)
    for t in np.flatnonzero(share > 0.0):
        mujoco.mj_differentiatePos(model, step, 1.0, out[t], targets[t])
        mujoco.mj_integratePos(model, out[t], step, share[t])
    return out


def offline_unexplainable(body: BodyModel, qpos: np.ndarray, fps: float, contacts: np.ndarray,
                          valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """What the whole B.4-refined input (T, nq) shows before any tracking, within its valid frames (T,) (None:
    all): (T, 4) contacts in which each whole-body flight of the labels that the motion's centre of mass does not
    fall through is held up by a point that stays within its foot's length and moves no faster than a contact
    (contacts.flights, the rule trajopt applies to the same labels), and (T,) bool the frames the contact model
    cannot explain, which both physics methods keep kinematic: a COM below the floor or a body resting off its
    feet (support.unexplained_frames), and such flights that no point can hold (every candidate travels). B.4
    leaves such flights where the kinematic feet hover over the floor: on one video 0.1 s needing 0.7 body
    weights, through which the character free-fell and landed at 4-5 body weights. Each stretch is logged."""
    mask = np.ones(len(qpos), bool) if valid is None else np.array(valid, bool)  # a copy: narrowed below
    pose = kin.forward_kinematics(body, qpos)
    com, points = kin.center_of_mass(body, pose), pose.points[:, body.point_index(CONTACT_POINTS)]
    unexplainable = observed_unexplained_frames(body.point_names, pose.points, com, fps, mask, "physics", contacts)
    mask &= ~unexplainable
    flags, unheld = held_flights_in_runs(np.asarray(contacts, bool) & mask[:, None], mask, com, points,
                                         np.arange(len(qpos)) / fps, GRAVITY,
                                         body.lengths.heel_back + body.lengths.toe_front, "physics")
    unexplainable |= unheld
    return flags, unexplainable


def onto_refined_floor(motion: KinematicMotion, physics: PhysicsMotion) -> tuple[KinematicMotion, PhysicsMotion]:
    """Both motions re-expressed in the world whose z = 0 plane is the floor the physics ended on (the camera
    follows), so that the result's floor is z = 0 as everywhere else; unchanged when the floor was not refined."""
    if physics.floor_plane is None:
        return motion, physics
    rotation, shift, _ = floor_frame(physics.floor_plane[:3], float(physics.floor_plane[3]))
    camera = motion.camera
    # x_camera = R_c x + t_c with x = R'(x_new - shift)
    R_camera = camera.R @ rotation.T
    new_camera = camera.with_extrinsics(R_camera, camera.t - R_camera @ shift)
    plane = floor_in_camera(new_camera.R, new_camera.t)
    floor = dataclasses.replace(motion.floor, normal=plane[:3], offset=float(plane[3]))
    motion = dataclasses.replace(motion, camera=new_camera, floor=floor,
                                 qpos=rigid_transform_qpos(motion.qpos, rotation, shift))
    residual = physics.residual.copy()
    residual[:, :3] = residual[:, :3] @ rotation.T  # the torque is in the pelvis frame
    physics = dataclasses.replace(physics, qpos=rigid_transform_qpos(physics.qpos, rotation, shift),
                                  grf=physics.grf @ rotation.T, residual=residual, floor_plane=None)
    return motion, physics
