"""PhysCap stage III (Shimada et al. 2020, section 4.3): per frame, causal, on the compiled MuJoCo body.

Each frame: (i) balance correction of stationary, unbalanced kinematic poses (4.3.1); then n times: (ii) desired
accelerations by PD control towards the kinematic pose (eq. 4); (iii) contact gating (eq. 5) and the ground
reaction forces that best explain the root's desired motion inside a linearised friction cone (eq. 6-7);
(iv) accelerations and torques that track the desired accelerations with small torques, subject to the
equation of motion with those forces and to contact velocity constraints (eq. 8-10); (v) semi-implicit Euler
integration (eq. 1). Whatever the forces cannot explain appears as direct actuation of the root (the residual).

Conventions: world Z up, floor z = 0; generalised velocities in MuJoCo's layout (root linear velocity in the
world, root angular velocity in the pelvis frame); forces in newtons.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import cast

import mujoco
import numpy as np

from ..body.model import CONTACT_POINTS, BodyModel
from ..config import PhysicsSettings
from ..contacts.flights import STANDING_SUPPORT
from .ballistic import TakeOffPath
from .qp import DenseQP

INF = 1e20  # daqp's "no bound"
MAX_ACCELERATION = 1e4  # m/s^2 or rad/s^2, about 50 times the fastest human limb motions: the state diverged
MAX_DESIRED_ACCELERATION = 2e3  # m/s^2 or rad/s^2, the PD targets' bound: about ten times the fastest human limb
# motions. A fit that flips a wrist back and forth between frames (60 rad/s each way, seen on real video) would
# otherwise ask the stiff PD for 1e4 and trip the divergence guard.


def stability_limit(settings: PhysicsSettings) -> float:
    """s: the step at which semi-implicit Euler on eq. (4)'s PD (x'' = -kp x - kd x') turns unstable on the stiffest
    DOF: kp h^2 + 2 kd h = 4, h = 4 / (kd + sqrt(kd^2 + 4 kp)); infinite without gains."""
    kp, kd = tracking_gains(settings, 7)  # the root's six DOFs and one joint: every distinct pair of gains
    return 4.0 / float(np.max(kd + np.sqrt(kd * kd + 4.0 * kp))) if np.any(kp + kd > 0.0) else math.inf


def integration_steps(settings: PhysicsSettings, fps: float) -> tuple[int, float]:
    """(steps per frame, step in s): with settings.step_stability_share, the fewest equal steps no longer than that
    share of the PD's stability limit (stability_limit) that fill one frame interval, so that the integration's
    stability and the PD's behaviour (gains in 1/s^2 and 1/s) do not depend on the frame rate; else the legacy
    settings.iterations steps of settings.step (or of one frame / iterations)."""
    if settings.step_stability_share is not None:
        longest = settings.step_stability_share * stability_limit(settings)
        steps = max(1, math.ceil(1.0 / (fps * longest) - 1e-9))
        return steps, 1.0 / (fps * steps)
    return settings.iterations, settings.step if settings.step is not None else 1.0 / (fps * settings.iterations)


@dataclass
class SubstepRecord:
    """One integration step, kept for tests and diagnostics (all in MuJoCo's coordinates)."""

    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    torque: np.ndarray  # (nv,) generalised forces besides contacts and gravity; [:6] is the root residual
    contact_forces: np.ndarray  # (4, 3) world frame
    active: np.ndarray  # (4,) contacts in use


@dataclass
class FrameOutput:
    """Averages over a frame's integration steps."""

    contact_forces: np.ndarray  # (4, 3) N, world frame
    residual: np.ndarray  # (6,) root force (world, N) and torque (pelvis frame, N m)
    active: np.ndarray  # (4,) bool, contacts used in the frame's last step
    qp_failures: int  # steps whose QP failed and fell back
    records: list[SubstepRecord] = field(default_factory=list)
    # (6,) root force (world, N) and torque (pelvis frame, N m) that the frame's kinematic motion needs and no
    # contact on the floor can give (PhysCapTracker.kinematic_misfit): the load hands or a raised floor carry
    unexplained: np.ndarray = field(default_factory=lambda: np.zeros(6))
    diverged: bool = False  # a step's accelerations diverged and the character restarted from the target
    # ((4, 3) N, (6,)) the contact forces and root residual fitted to the root wrench the frame's motion needed (eq.
    # 6-7 on the steps' mean M qdd + c, at the last step's contacts), None without contacts: see PhysicsStream
    motion_forces: tuple[np.ndarray, np.ndarray] | None = None
    # (the interval's start frame's, its end frame's) shares of motion_forces, each (forces (4, 3) N, residual (6,)):
    # each step's impulse split between the two frames by its closeness to each (PhysCapTracker.split_forces)
    shares: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
    unexplained_flag: bool = False  # set by the stage's diagnosis (stage.PhysicsStream)
    tracked: bool = True  # False: the stream kept the target without tracking it, no force claimed (stage)


def tracking_gains(settings: PhysicsSettings, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """(nv,) kp in 1/s^2 and (nv,) kd in 1/s of eq. (4) per DOF: root translation, root rotation, joints."""
    kp, kd = np.full(nv, settings.kp_joint, dtype=float), np.full(nv, settings.kd_joint, dtype=float)
    kp[:3], kd[:3] = settings.kp_root_translation, settings.kd_root_translation
    # The root's horizontal position: the fit's noise there, tracked stiffly, became frame-to-frame horizontal
    # contact forces (docs/decisions/physics-grf-chatter.md); its height stays stiff for take-offs and landings.
    if settings.kp_root_horizontal is not None:
        kp[:2] = settings.kp_root_horizontal
    if settings.kd_root_horizontal is not None:
        kd[:2] = settings.kd_root_horizontal
    kp[3:6], kd[3:6] = settings.kp_root_rotation, settings.kd_root_rotation
    return kp, kd


def feedforward_shares(settings: PhysicsSettings, kd: np.ndarray, fps: float) -> np.ndarray:
    """Eq. (4)'s fed-forward share of the kinematic acceleration per DOF, for damping kd (n,) 1/s at `fps`: between
    frames the target is a chord, whose velocity step at the frame the damping alone reaches by the interval's end
    when the acceleration is fed forward at x / (e^x - 1), x = kd / fps (1 as the interval vanishes, the paper's
    continuous form), times settings.acceleration_feedforward: a larger share overshoots the chord
    (docs/decisions/physics-video-jitter.md)."""
    frame_damping = np.asarray(kd, dtype=float) / fps
    return settings.acceleration_feedforward * np.divide(frame_damping, np.expm1(frame_damping),
                                                         out=np.ones(len(frame_damping)), where=frame_damping > 0.0)


def within_bound(forces: np.ndarray, residual: np.ndarray, bound: float) -> bool:
    """The summed contact force (4, 3), the residual's force and its torque (6,) each no larger than bound (N; the
    torque in N m); False for non-finite values. In floats: numpy's norms cost more than the arithmetic."""
    (fx, fy, fz), (rx, ry, rz, tx, ty, tz) = forces.sum(axis=0).tolist(), residual.tolist()
    squares = (fx * fx + fy * fy + fz * fz, rx * rx + ry * ry + rz * rz, tx * tx + ty * ty + tz * tz)
    return all(square <= bound * bound for square in squares)  # NaN fails


def frame_share_weights(substeps: int) -> tuple[float, float]:
    """(start frame's, end frame's) shares of an interval's impulse over `substeps` semi-implicit Euler steps
    (PhysCapTracker._frame_shares): (n + 1) / 2n and (n - 1) / 2n."""
    return (substeps + 1) / (2 * substeps), (substeps - 1) / (2 * substeps)


def _bounded(qdd: np.ndarray) -> bool:
    """Every acceleration (nv,) finite and within MAX_ACCELERATION: the step is not diverging."""
    accelerations = qdd.tolist()  # in floats: numpy's reductions cost more than the comparison
    return (-MAX_ACCELERATION < min(accelerations) and max(accelerations) < MAX_ACCELERATION
            and math.isfinite(sum(accelerations)))  # the sum catches NaN, which min and max may skip


class PhysCapTracker:
    """The physics-based character tracking a kinematic motion. One per clip (it holds the state q, qdot)."""

    def __init__(self, body: BodyModel, settings: PhysicsSettings, fps: float, record: bool = False,
                 settle_contacts: bool = True):
        """settle_contacts: held contact points above their target are brought down to it
        (settings.contact_settle_time); the stage turns it off for targets it lifts itself (online fits)."""
        self.body, self.settings, self.record = body, settings, record
        self.settle_contacts = settle_contacts
        self.split_forces = False  # FrameOutput.shares too (the forces at the frames' instants: stage.forces_at_frames)
        self.model = copy.copy(body.mujoco_model())  # its own: the foot geoms get the touch margin
        self.data = mujoco.MjData(self.model)
        nv = self.model.nv
        self.substeps, self.dt = integration_steps(settings, fps)
        self.kp, self.kd = tracking_gains(settings, nv)
        self.feedforward = feedforward_shares(settings, self.kd, fps)
        # kd times the share of the kinematic velocity in the derivative term (settings.rotation_velocity_share)
        self.kd_target = self.kd.copy()
        self.kd_target[3:] *= settings.rotation_velocity_share
        self._prepare_contacts_and_qps(settings, nv)
        self.contact_jacobian = np.zeros((4, 3, nv))
        self.qpos, self.qvel = self.data.qpos, self.data.qvel  # the state, where the step's dynamics read it
        self.target_data = mujoco.MjData(self.model)  # kinematics of the frame's target pose
        self._previous_target = np.zeros(self.model.nq)  # the last frame's target: the steps move from it
        self._previous_target_heights = np.zeros(4)  # m, its contact points' heights
        self._previous_contacts: np.ndarray | None = None  # the last frame's predicted contacts (None after a reset)
        self._released = [False, False, False, False]  # the last frame's released contacts (_released_contacts)
        self._supporting = [False, False, False, False]  # released points kept as the last support (_last_support)
        # body weights: the upward force the targets needed (kinematic_misfit), averaged over unexplained_time as
        # the diagnosis averages the force they lack; and the share of a new frame's value in the average
        self.needed_support = 1.0
        self._support_share = 1.0 - math.exp(-1.0 / (fps * settings.unexplained_time))
        self._weight = body.mass * -float(self.model.opt.gravity[2])  # N
        self._previous_target_xy = [[0.0, 0.0]] * 4  # m, the last frame's target contact points along the floor
        self._target_step = np.zeros(nv)
        self._pose_error, self._desired = np.zeros(nv), np.zeros(nv)  # desired_acceleration's buffers
        self._weight_column = self.torque_weights[:, None]
        # The step's small bookkeeping (four contact points) runs on Python lists and tuples: numpy's cost per call
        # outweighs the arithmetic on four values. Per tuple of active flags: the contacts' indices (list and array,
        # which index the Jacobians as the flags would) and the flags as an array.
        self._contact_index: dict[tuple[bool, ...], tuple[list[int], np.ndarray, np.ndarray]] = {}
        for mask in range(16):
            flags = tuple(bool(mask >> j & 1) for j in range(4))
            indices = [j for j in range(4) if flags[j]]
            self._contact_index[flags] = (indices, np.array(indices, dtype=np.intp), np.array(flags))
        self._jacobian_columns = self.contact_jacobian.reshape(12, nv).T  # J^T of all contact points, a view
        self._site_jacobians = [(int(site), self.contact_jacobian[j]) for j, site in enumerate(self.sites)]
        self._weighted_force, self._external = np.zeros(nv), np.zeros(nv)  # pose_accelerations' buffers (J^T lambda)
        self._mass_root, self._bias_root = self.mass_matrix[:6], self.bias[:6]  # the root's rows, views
        # s: eq. (9)'s times to recover a penetration and to settle a held contact, never shorter than a step
        self._recovery_time = max(self.dt, settings.penetration_recovery)
        self._settle_time = max(self.dt, settings.contact_settle_time)

    def _prepare_contacts_and_qps(self, settings: PhysicsSettings, nv: int) -> None:
        """The contact points' sites and touch margin, and the QPs' weights, friction pyramid and workspaces
        (the pose QP, eq. 10; the force QPs, eqs. 6-7, one per number of active contacts)."""
        self.sites = np.array([self.model.site(n).id for n in CONTACT_POINTS])
        self._contact_of_geom = [-1] * self.model.ngeom  # geom id -> contact point index, -1 for others
        for j, name in enumerate(CONTACT_POINTS):
            geom = self.model.geom(f"{name}_collision").id
            self._contact_of_geom[geom] = j
            self.model.geom_margin[geom] = settings.touch_margin
        self.torque_weights = np.full(nv, settings.torque_weight)
        self.torque_weights[:6] = settings.residual_weight
        self.torque_weights[2] = settings.residual_weight_vertical
        mu = settings.friction / np.sqrt(2.0)
        # Friction pyramid rows per contact: mu*fz -+ fx >= 0, mu*fz -+ fy >= 0.
        self.pyramid = np.array([[-1.0, 0.0, mu], [1.0, 0.0, mu], [0.0, -1.0, mu], [0.0, 1.0, mu]])
        self.mass_matrix = np.zeros((nv, nv))
        self.bias = np.zeros(nv)
        self.identity = np.eye(nv)
        self._weighted_mass = np.zeros((nv, nv))
        # The pose QP (eq. 10): its H is built in the workspace's own buffer; at most 3 rows per contact point.
        self._pose_qp = DenseQP(nv, 12)
        # H = A A^T has rank 6: at a regularisation of 1e-6 daqp called 8% of the demo clip's frames infeasible;
        # 1e-4 N^-2 costs a bias of 1e-4 of the force. Per number of active contacts k: the regularisation (3k, 3k)
        # and a workspace holding the pyramid rows (4k, 3k) and their bounds (each row >= 0).
        self._grf_regularisation = [1e-4 * np.eye(3 * k) for k in range(5)]
        self._grf_qps = [DenseQP(3 * k, 4 * k) for k in range(5)]
        for k, qp in enumerate(self._grf_qps):
            qp.A[:] = np.kron(np.eye(k), self.pyramid)
            qp.upper[:], qp.lower[:] = INF, 0.0

    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        self.qpos[:] = qpos
        self.qvel[:] = qvel
        self._previous_target[:] = qpos
        self._target_kinematics(qpos)
        self._previous_target_heights[:] = self.target_data.site_xpos[self.sites, 2]
        self._previous_contacts = None
        self._released = [False, False, False, False]
        self._supporting = [False, False, False, False]
        self.needed_support = 1.0
        self._previous_target_xy = self.target_data.site_xpos[self.sites, :2].tolist()

    def _target_kinematics(self, q_kin: np.ndarray) -> None:
        self.target_data.qpos[:] = q_kin
        mujoco.mj_kinematics(self.model, self.target_data)

    # ---- the pieces of one step -------------------------------------------------------------------------
    def _step_state(self) -> tuple[list[float], list[bool]]:
        """Mass matrix, bias forces and contact Jacobians at the state into the step buffers; returns the contact
        points' heights (m) and floor collisions, lists of four."""
        d = self.data
        self._rigid_body_terms(d, collide=True)
        touching = [False, False, False, False]
        if d.ncon:
            contact_of_geom = self._contact_of_geom
            for pair in d.contact.geom.tolist():  # the ncon contacts' geom pairs
                for geom in pair:
                    if contact_of_geom[geom] >= 0:
                        touching[contact_of_geom[geom]] = True
        return d.site_xpos[self.sites, 2].tolist(), touching

    def desired_acceleration(self, q_kin, qd_kin, qdd_kin) -> np.ndarray:
        """Eq. (4): PD control towards the kinematic pose; the pose error is taken on the manifold, the
        kinematic acceleration is fed forward scaled by self.feedforward and the rotational
        velocities by settings.rotation_velocity_share; bounded by MAX_DESIRED_ACCELERATION."""
        return self._desired_acceleration(q_kin, self.feedforward * qdd_kin,
                                          self.kd_target * qd_kin).copy()

    def _desired_acceleration(self, q_kin, feedforward, target_damping) -> np.ndarray:
        """desired_acceleration with its per-frame terms (feedforward qdd_kin, kd_target qd_kin)
        given, into a buffer the next call overwrites."""
        error, desired = self._pose_error, self._desired
        mujoco.mj_differentiatePos(self.model, error, 1.0, self.qpos, q_kin)
        np.multiply(self.kp, error, out=error)
        np.add(feedforward, error, out=desired)
        desired += target_damping
        desired -= np.multiply(self.kd, self.qvel, out=error)
        np.maximum(desired, -MAX_DESIRED_ACCELERATION, out=desired)
        return np.minimum(desired, MAX_DESIRED_ACCELERATION, out=desired)

    def ground_reaction_forces(self, qdd_des, active: tuple[bool, ...],
                               unexplained: bool) -> tuple[np.ndarray, bool, np.ndarray | None]:
        """Eq. (6-7): forces (4, 3) at the active contacts (flags of four) that best produce the root's desired
        acceleration at the state `_rigid_body_terms` left in the step buffers, pushing only, inside the friction
        pyramid. Returns the forces, whether the QP solved, and where asked (else None) the root wrench (6,) the
        forces leave unexplained (the desired one where no contact is active or the QP failed)."""
        return self.forces_for_root_wrench(self._mass_root @ qdd_des + self._bias_root, active, unexplained)

    def forces_for_root_wrench(self, target: np.ndarray, active: tuple[bool, ...],
                               unexplained: bool) -> tuple[np.ndarray, bool, np.ndarray | None]:
        """Eq. (6-7) for a given root wrench (6,): ground_reaction_forces' fit, at the contact Jacobians in the
        step buffers, and its returns."""
        index = self._contact_index[active][1]
        forces = np.zeros((4, 3))
        k = len(index)
        if not k:
            return forces, True, target
        root_rows = self.contact_jacobian[index, :, :6].reshape(3 * k, 6)  # (J^T restricted to the root)^T
        qp = self._grf_qps[k]
        np.add(np.matmul(root_rows, root_rows.T, out=qp.H), self._grf_regularisation[k], out=qp.H)
        np.matmul(np.negative(root_rows), target, out=qp.f)
        x, exitflag = qp.solve(4 * k)
        if exitflag != 1:
            return forces, False, target
        forces[index] = x.reshape(k, 3)
        return forces, True, target - root_rows.T @ x if unexplained else None

    def pose_accelerations(self, qdd_des, bias, forces, active: tuple[bool, ...], heights: list[float],
                           released: list[bool], target_heights: list[float]) -> tuple[np.ndarray, np.ndarray, bool]:
        """Eq. (10): qdd minimising |qdd - qdd_des|^2 + tau' W tau with tau = M qdd + c - J^T lambda (the
        equation of motion, eq. 2), subject to eq. (9) at the active contacts (flags of four) after the step: the
        normal velocity keeps the point on or above the floor and (settle_contacts) brings a point above its
        target's height (target_heights, m) down to it within settings.contact_settle_time, tangential speeds
        stay within sigma (except at released contacts, which slide freely but still do not sink). heights,
        released and target_heights: lists of four (Python values: see __init__).
        Returns qdd, tau and whether the QP solved (else the unconstrained optimum is used)."""
        contacts, index, _ = self._contact_index[active]
        M, qp = self.mass_matrix, self._pose_qp
        external = np.matmul(self._jacobian_columns, forces.ravel(), out=self._external)
        # The objective is 1/2 qdd' H qdd + f' qdd up to a constant and a factor 2: H = I + M W M, built in
        # preallocated buffers (it is rebuilt at every step).
        np.multiply(self._weight_column, M, out=self._weighted_mass)
        H = np.matmul(M, self._weighted_mass, out=qp.H)
        H += self.identity
        weighted = np.multiply(self.torque_weights, np.subtract(bias, external, out=self._weighted_force),
                               out=self._weighted_force)
        np.subtract(np.matmul(M, weighted, out=qp.f), qdd_des, out=qp.f)
        solved = True
        if contacts:
            rows = self.contact_jacobian[index].reshape(-1, self.model.nv)  # x, y, z rows of each active contact
            velocity = (rows @ self.qvel).tolist()
            m = len(velocity)
            qp.lower[:m], qp.upper[:m] = self._velocity_bounds(contacts, velocity, heights, released, target_heights)
            np.multiply(self.dt, rows, out=qp.A[:m])
            qdd, exitflag = qp.solve(m)
            solved = exitflag == 1
        if not contacts or not solved:
            qdd = self._unconstrained()
        return qdd, M @ qdd + bias - external, solved

    def _velocity_bounds(self, contacts: list[int], velocity: list[float], heights: list[float],
                         released: list[bool], target_heights: list[float]) -> tuple[list[float], list[float]]:
        """Eq. (9)'s bounds (lower, upper) on the x, y, z velocity changes of the active contacts over the step
        (pose_accelerations), from their velocities (3k,) and the points' heights, release flags and target
        heights (4,); in Python floats, as numpy's cost per call outweighs the arithmetic on so few values."""
        dt, slide_speed, clearance = self.dt, self.settings.slide_speed, self.settings.floor_clearance
        recovery, settle_time = self._recovery_time, self._settle_time
        lower: list[float] = []
        upper: list[float] = []
        for index, j in enumerate(contacts):
            vx, vy, vz = velocity[3 * index:3 * index + 3]
            slide, h = INF if released[j] else slide_speed, heights[j]
            # Above the floor: come down at most to the clearance by the end of the step (the step's rotation
            # may dip the point by less than that); within it: do not descend; below the floor: rise back gently.
            # (b if b > a else a is max(a, b), without the call.)
            normal_speed = (clearance - h) / dt if h > clearance else (0.0 if 0.0 > -h else -h) / recovery
            rise = INF
            if self.settle_contacts:
                goal = clearance if clearance > target_heights[j] else target_heights[j]
                settle = (goal - h) / settle_time if h > goal else INF
                rise = (normal_speed if normal_speed > settle else settle) - vz
            lower += (-slide - vx, -slide - vy, normal_speed - vz)
            upper += (slide - vx, slide - vy, rise)
        return lower, upper

    def _unconstrained(self) -> np.ndarray:
        """argmin 1/2 x'Hx + f'x of the pose QP's H and f by daqp's own factorisation: LAPACK's solve for a 40x40
        system took 0.6 ms when numpy's BLAS ran two threads on a busy machine, daqp about 30 us."""
        qp = self._pose_qp
        x, exitflag = qp.solve(0)
        return x if exitflag == 1 else np.linalg.solve(qp.H, -qp.f)

    def _released_contacts(self, target_sites: np.ndarray, predicted: list[bool]) -> list[bool]:
        """Flags of the four contact points whose target (target_sites, (4, 3) m) lies more than release_distance
        along the floor from where the character holds them: the kinematic foot has gone (a wrong contact label or
        the detector swapping the feet), and holding on would drag the whole body after it. A released point stays
        released until its target moves slower than slide_speed: caught again while its target slides on, it was
        stopped within a step and let go the next frame (docs/decisions/physics-video-jitter.md). Sets
        `_supporting` (_last_support). Reads the character's contact points from `_step_state`, which must have run
        at the current state. In Python floats (numpy's cost per call outweighs the arithmetic on four points)."""
        limit = self.settings.release_distance
        if limit is None:
            return [False, False, False, False]
        slide = self.settings.slide_speed * self.substeps * self.dt  # m per frame interval
        released = []
        character = self.data.site_xpos[self.sites].tolist()
        for j, ((aim_x, aim_y, _), (x, y, _), (last_x, last_y)) in enumerate(zip(
                target_sites.tolist(), character, self._previous_target_xy, strict=True)):
            sliding = math.sqrt((aim_x - last_x) * (aim_x - last_x) + (aim_y - last_y) * (aim_y - last_y)) > slide
            released.append(math.sqrt((aim_x - x) * (aim_x - x) + (aim_y - y) * (aim_y - y)) > limit
                            or (self._released[j] and sliding))
        self._released = released
        self._previous_target_xy = target_sites[:, :2].tolist()
        self._supporting = (self._last_support(released, predicted, [point[2] for point in character])
                            if True in released else [False, False, False, False])
        return released

    def _last_support(self, released: list[bool], predicted: list[bool], heights: list[float]) -> list[bool]:
        """Flags of released points (released, predicted, heights: the character's points, m; lists of four)
        that stay active as supports sliding freely, because the release took away every support that eq. (5)
        grants (predicted, within contact_height) while the target still needs at least half its weight from the
        floor (needed_support; a target in flight needs none). Released without a support, a body standing on a
        toe the target rolls off free-fell until its swing foot touched down, then landed at up to 8 body weights
        (docs/decisions/physics-online-support.md); holding the point within slide_speed instead dragged it."""
        height = self.settings.contact_height
        near = [predicted[j] and heights[j] < height for j in range(4)]
        if self.needed_support < STANDING_SUPPORT or any(near[j] and not released[j] for j in range(4)):
            return [False, False, False, False]
        return [near[j] and released[j] for j in range(4)]

    def release_contacts(self, kinematic_points: np.ndarray,
                         predicted: np.ndarray) -> tuple[list[bool], np.ndarray]:
        """The frame's released contacts (_released_contacts) judged before `track` (which then takes them),
        against kinematic_points (4, 3) m: for a target whose feet the stream plants (planting.FootPlanter), where
        the planted target's points lie; predicted: the frame's predicted contacts (4,). Returns them and the
        character's contact points (4, 3) m at the current state."""
        mujoco.mj_kinematics(self.model, self.data)
        return (self._released_contacts(kinematic_points, predicted.tolist()),
                self.data.site_xpos[self.sites].copy())

    # ---- one video frame ----------------------------------------------------------------------------------
    def track(self, q_kin: np.ndarray, qd_kin: np.ndarray, qdd_kin: np.ndarray,
              predicted_contacts: np.ndarray, released: list[bool] | None = None,
              take_off: TakeOffPath | None = None) -> FrameOutput:
        """Advance the character by one frame towards the kinematic pose (steps ii-v, n times). released: the
        frame's released contacts from release_contacts (None: judged here against the target's points). take_off:
        the centre of mass's vertical path through an interval that ends at a flight's first frame
        (ballistic.TakeOffPath): its offsets from the chord move the root's height target, velocity and fed-forward
        acceleration step by step, its switch times the contacts' release, and until then held points may rise
        above their target's (the settle would pull the pushing feet back to the chord's)."""
        s, n = self.settings, self.substeps
        forces_sum, residual_sum, root_forces_sum = np.zeros((4, 3)), np.zeros(6), np.zeros(6)
        later_sum = np.zeros(6)  # the steps' root wrenches, step i weighted by i (split_forces)
        failures, diverged, records, target = 0, False, [], np.empty_like(q_kin)
        # The steps advance the character through the frame: step i aims at the pose interpolated (on the
        # manifold) between the last frame's target and this one at the step's end time, so that the last step
        # lands on frame t whatever the number of steps.
        mujoco.mj_differentiatePos(self.model, self._target_step, 1.0, self._previous_target, q_kin)
        # Contacts are decided per step, so that they switch at the same instants at any frame rate: each step
        # takes the predicted contacts of the frame nearest its middle (the last frame's over the first half of
        # the interval), and the target's contact heights are interpolated like the pose.
        self._target_kinematics(q_kin)
        target_sites = self.target_data.site_xpos[self.sites].copy()
        height_step = target_sites[:, 2] - self._previous_target_heights
        earlier_contacts = (predicted_contacts if self._previous_contacts is None
                            else self._previous_contacts).tolist()
        later_contacts = predicted_contacts.tolist()
        previous_heights, height_step = self._previous_target_heights.tolist(), height_step.tolist()
        feedforward, target_damping = self.feedforward * qdd_kin, self.kd_target * qd_kin
        contact_height, touch = s.contact_height, s.foot_lock != "never"  # never: a floor that does not push back
        flags: tuple[bool, ...] = (False, False, False, False)
        switch = 0.5 if take_off is None else take_off.switch
        if take_off is not None:
            feedforward, target_damping = feedforward.copy(), target_damping.copy()
            kd_vertical = float(self.kd_target[2])
            # the path's height and velocity offsets from the centre of mass's chord, on the root's chord
            root_chord = float(self._target_step[2]) / (n * self.dt)
        for i in range(n):
            target[:] = self._previous_target
            mujoco.mj_integratePos(self.model, target, self._target_step, (i + 1) / n)
            if take_off is not None:
                height, velocity, acceleration = take_off.offsets((i + 1) / n)
                target[2] += height
                target_damping[2] = kd_vertical * (root_chord + velocity)
                feedforward[2] = acceleration
            heights, touching = self._step_state()
            if released is None:  # judged once per frame against the frame's target (per step it split walks)
                released = self._released_contacts(target_sites, later_contacts)
            supporting = self._supporting
            before_switch = (i + 0.5) / n < switch  # the step's middle: the last frame's contacts still
            predicted = earlier_contacts if before_switch else later_contacts
            # eq. (5): predicted, within contact_height and not released (or the last support); or touching the floor
            flags = tuple([(predicted[j] and heights[j] < contact_height and (not released[j] or supporting[j]))
                           or (touch and touching[j]) for j in range(4)])
            qdd_des = self._desired_acceleration(target, feedforward, target_damping)
            forces, grf_ok, _ = self.ground_reaction_forces(qdd_des, flags, False)
            fraction = (i + 1) / n
            qdd, torque, pose_ok = self.pose_accelerations(
                qdd_des, self.bias, forces, flags, heights, released,
                [height + fraction * step for height, step in zip(previous_heights, height_step, strict=True)]
                if take_off is None or not before_switch else [INF, INF, INF, INF])
            failures += (not grf_ok) + (not pose_ok)
            if self.record:
                records.append(SubstepRecord(self.qpos.copy(), self.qvel.copy(), qdd, torque, forces,
                                             self._contact_index[flags][2].copy()))
            if not _bounded(qdd):
                # Diverging (a wildly implausible target): restart from the target at rest, counted as a fallback.
                failures, diverged = failures + 1, True
                self.reset(target, np.zeros_like(self.qvel))
                continue
            self.qvel += self.dt * qdd  # eq. (1): velocity first, then position with the new velocity
            mujoco.mj_integratePos(self.model, self.qpos, self.qvel, self.dt)
            forces_sum += forces
            residual_sum += torque[:6]
            root_forces_sum += self._external[:6]  # with the residual: the root wrench M qdd + c of the step
            if self.split_forces:
                later_sum += i * (torque[:6] + self._external[:6])
        self._remember_frame(q_kin, target_sites, predicted_contacts)
        motion_forces = None if diverged else self._motion_forces((residual_sum + root_forces_sum) / n, flags)
        shares = None
        if self.split_forces and motion_forces is not None:
            shares = self._frame_shares(residual_sum + root_forces_sum, later_sum, motion_forces, flags)
        unexplained = self.kinematic_misfit(q_kin, qd_kin, qdd_kin)
        return FrameOutput(forces_sum / n, residual_sum / n, self._contact_index[flags][2].copy(), failures, records,
                           unexplained, diverged, motion_forces=motion_forces, shares=shares)

    def _frame_shares(self, total: np.ndarray, later: np.ndarray, motion_forces: tuple[np.ndarray, np.ndarray],
                      active: tuple[bool, ...]):
        """FrameOutput.shares from the sums over the interval's n steps of the root wrench (6,), plain (total) and
        step i (0 .. n-1) weighted by i (later). The character's positions at the frames (semi-implicit Euler: a
        step's velocity moves that step's position) bend by (x[t+1] - 2 x[t] + x[t-1]) = dt^2 (sum over the
        interval before frame t of i a_i + sum over the one after it of (n - i) a_i): so the end frame takes
        sum i w_i / n^2 of the interval's impulse, its start frame sum (n - i) w_i / n^2, and a frame's two shares
        add up to the force its central second difference reads (the interval mean stamped on both frames lagged
        the motion by a third to half a frame: docs/decisions/physics-force-timing.md). Each share is fitted to
        the contacts (eq. 6-7) as a unit-weight wrench, then scaled by its weight ((n -/+ 1) / 2n), so that both
        stay admissible; None where a fit fails."""
        n = self.substeps
        if n == 1:  # all of the step's impulse belongs to the frame it starts at
            return motion_forces, (np.zeros((4, 3)), np.zeros(6))
        start_weight, end_weight = frame_share_weights(n)
        start = self._motion_forces((n * total - later) / (n * n * start_weight), active)
        end = self._motion_forces(later / (n * n * end_weight), active)
        bound = self.settings.max_force * self._weight  # each within it, so is a frame's sum of two shares
        if start is None or end is None or not (within_bound(*start, bound) and within_bound(*end, bound)):
            return None
        return ((start_weight * start[0], start_weight * start[1]), (end_weight * end[0], end_weight * end[1]))

    def _remember_frame(self, q_kin: np.ndarray, target_sites: np.ndarray, predicted_contacts: np.ndarray) -> None:
        """The frame's target pose (nq,), its contact points' heights (from target_sites (4, 3), m) and predicted
        contacts (4,): where the next frame's steps start."""
        self._previous_target[:] = q_kin
        self._previous_target_heights[:] = target_sites[:, 2]
        self._previous_contacts = predicted_contacts.copy()

    def _motion_forces(self, root_wrench: np.ndarray,
                       active: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray] | None:
        """FrameOutput.motion_forces: eq. (6-7) fitted to the root wrench (6,) the frame's steps needed, at the active
        contacts and Jacobians of its last step (still in the step buffers); None without contacts or solution."""
        if not any(active):
            return None
        forces, solved, left = self.forces_for_root_wrench(root_wrench, active, True)
        return (forces, cast(np.ndarray, left)) if solved else None

    def _rigid_body_terms(self, d: mujoco.MjData, collide: bool) -> None:
        """Into d and the step buffers: kinematics, composite inertia, (collisions,) the bias forces
        (self.bias), the mass matrix (self.mass_matrix) and the contact sites' Jacobians; only the pieces used,
        no constraint solver."""
        m = self.model
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_crb(m, d)
        if collide:
            mujoco.mj_collision(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 0, self.bias)
        mujoco.mj_fullM(m, d, self.mass_matrix)
        for site, jacobian in self._site_jacobians:
            mujoco.mj_jacSite(m, d, jacobian, None, site)

    def kinematic_misfit(self, q_kin: np.ndarray, qd_kin: np.ndarray, qdd_kin: np.ndarray) -> np.ndarray:
        """(6,) the root force (world, N) and torque (pelvis frame, N m) that the kinematic motion itself needs
        (inverse dynamics at its pose, velocity and acceleration) and that no admissible force at its sole points
        within contact_height of the floor can give (eq. 6-7 solved for the kinematic motion), whatever the
        predicted contacts: zero in flight that follows gravity and on feet that carry the body, about the
        body's weight where hands or a raised floor carry it. A missed contact label is the tracker's problem, not
        the contact model's (the stray check catches what it costs). Also averages the upward force the motion
        needs into needed_support. Overwrites the step buffers (recomputed at the next step)."""
        d = self.target_data
        d.qpos[:], d.qvel[:] = q_kin, qd_kin
        self._rigid_body_terms(d, collide=False)
        contact_height = self.settings.contact_height
        flags = tuple([height < contact_height for height in d.site_xpos[self.sites, 2].tolist()])
        wrench = self._mass_root @ qdd_kin + self._bias_root
        self.needed_support += self._support_share * (float(wrench[2]) / self._weight - self.needed_support)
        return cast(np.ndarray, self.forces_for_root_wrench(wrench, flags, True)[2])
