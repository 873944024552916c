"""Fixed-bone-length inverse kinematics over time: PhysCap eq. (3), solved by Levenberg-Marquardt.

Energy terms (each a small named piece with its residual and analytic Jacobian, in metres):
- reprojection (E_proj): detected 2D keypoints against projected model points, weighted by confidence and
  scaled by the person's depth over the focal length, so a pixel error reads as metres at the person;
- 3D data (E_IK): root-relative model points against the detector's 3D landmarks;
- smoothness (E_smooth): acceleration of the joints in the world;
- depth (E_depth): change of the joints' distance along the camera axis between frames;
- pose prior and hinge limits, which keep unobservable twists at rest and knees/elbows bending one way;
- optional terms of Rempe et al. 2020 (B.3), off unless their weights are set: contact velocity (B6, heels and
  toes still between two frames labelled in contact), contact position on the floor (B7), velocity of the
  pelvis-relative joints (B2) and change of the joint angles (B3). Contact labels and the floor plane come with
  the targets (FitTargets.contacts, FitTargets.floor);
- optional, ours, offline only: acceleration of the centre of mass, against free fall where no foot is in contact
  (FitTargets.free_fall), so that the forces the motion implies are not its noise twice differentiated.

Two solvers share these terms: offline over the whole clip (block-banded normal equations, block Cholesky by
pairs of frames), and per frame with the previous two frames fixed (`fit_frames`, constant cost per frame),
batched over independent frames: the online fit is one causal stream, the offline fit starts from many at once.
Variables are steps in MuJoCo's velocity space applied on the manifold.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.linalg import LinAlgError
from scipy.linalg.lapack import dpotrf, dtrtrs

from ..body import kinematics as kin
from ..body.model import CONTACT_POINTS, JOINT_NAMES, BodyModel
from ..body.rotations import (
    matrix_to_quat,
    quat_conjugate,
    quat_left_matrix,
    quat_log,
    so3_right_jacobian_inverse,
    unwrap_rotation_vectors,
)
from ..body.support import RESTING_HEIGHT
from ..camera import Camera
from ..config import FitSettings
from ..landmarks import LANDMARK_INDEX
from ..metrics import GRAVITY

# Detector landmarks fitted, and the model point each one observes.
MARKERS: tuple[tuple[str, str], ...] = (
    ("nose", "nose"), ("left_eye", "left_eye"), ("right_eye", "right_eye"), ("left_ear", "left_ear"),
    ("right_ear", "right_ear"), ("left_shoulder", "left_shoulder"), ("right_shoulder", "right_shoulder"),
    ("left_elbow", "left_elbow"), ("right_elbow", "right_elbow"), ("left_wrist", "left_wrist"),
    ("right_wrist", "right_wrist"), ("left_pinky", "left_pinky"), ("right_pinky", "right_pinky"),
    ("left_index", "left_index"), ("right_index", "right_index"), ("left_hip", "left_hip"),
    ("right_hip", "right_hip"), ("left_knee", "left_knee"), ("right_knee", "right_knee"),
    ("left_ankle", "left_ankle"), ("right_ankle", "right_ankle"), ("left_heel", "left_heel"),
    ("right_heel", "right_heel"), ("left_foot_index", "left_toe"), ("right_foot_index", "right_toe"),
)
MARKER_LANDMARKS = np.array([LANDMARK_INDEX[a] for a, _ in MARKERS])

# Initial Levenberg-Marquardt damping (offline: relative to the diagonal of the frames' own terms; online: to the
# normal matrix's). The whole-clip problem starts far from its optimum and overshoots with less (measured when
# relative to the whole diagonal: 9 instead of 24 evaluations to the same cost; from the
# batched causal start, 1.0 still had 3 of 11 steps rejected on taiji, 3.0 none: offline CPU ms/frame 5.28 -> 4.64
# taiji, 5.68 -> 5.03 sports2d, reprojection 5.46 -> 5.39 / 5.29 -> 5.20 px, synthetic root-relative 32.3 -> 32.4
# mm); one warm-started frame starts close and converges fastest with little.
OFFLINE_DAMPING = 3.0
ONLINE_DAMPING = 1e-3
LM_TOLERANCE = 1e-3  # a Levenberg-Marquardt fit stops after a step that lowers its cost by less than this fraction
# Frames (1 or more) whose Jacobians the whole-clip fit holds at once while it assembles its system (about 0.2 MB
# a frame): the assembly's memory is bounded by this, not by the clip. See docs/decisions/fit-memory.md.
ASSEMBLY_FRAMES = 256
TEMPORAL_REACH = 2  # frames after a frame that its temporal residuals reach (the acceleration's three frames)
STATED_FPS = 30.0  # frames per second at which FitSettings' temporal weights and steps per frame are stated
# A body runs where its root travels faster than the walk-run transition, Froude number v^2 / (g leg) = 0.5
# (Alexander 1989; measured 0.5 by Kram et al. 1997), over a running stride centred on the frame (two steps at about
# 170 steps a minute), with a foot in contact in each step: the stride's net travel leaves out the bounce of each
# step and a detector's drift, the stances a body carried, thrown or only extrapolated between observed frames.
WALK_RUN_FROUDE = 0.5
RUNNING_STRIDE = 0.7  # s
# A temporal term: values (T, n), Jacobians (T, n, nv), coefficients of the difference, pair weights (T - 1, n) or None
Signal = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]


@dataclass
class FitTargets:
    """Per-frame data the fit pulls towards. M markers.

    keypoints: (T, M, 2) pixels; weight_2d: (T, M) sqrt of weight times confidence (0 = unseen);
    targets_3d: (T, M, 3) root-relative positions in the world frame, metres; weight_3d: (T, M);
    depth: (T,) the person's distance along the camera axis, metres, used to express pixels as metres.
    contacts: optional (T, 4) contact weights in 0..1 of the heel and toe sites (CONTACT_POINTS order: l heel,
        l toe, r heel, r toe), for the contact velocity and floor terms; None: no contact terms.
    floor: optional (4,) plane n . x + d = 0 in the fit's world frame, n the unit normal pointing up, for the
        floor term; None: no floor term.
    free_fall: optional (T, 3) metres, a path whose second differences are gravity's on the frames where the person
        is observed and no foot is in contact, zero elsewhere: the centre of mass's acceleration term pulls towards
        it (`with_free_fall`); None: towards no acceleration.
    """

    keypoints: np.ndarray
    weight_2d: np.ndarray
    targets_3d: np.ndarray
    weight_3d: np.ndarray
    depth: np.ndarray
    contacts: np.ndarray | None = None
    floor: np.ndarray | None = None
    free_fall: np.ndarray | None = None

    def frames(self, sl: slice | np.ndarray) -> FitTargets:
        return FitTargets(self.keypoints[sl], self.weight_2d[sl], self.targets_3d[sl], self.weight_3d[sl],
                          self.depth[sl], None if self.contacts is None else self.contacts[sl], self.floor,
                          None if self.free_fall is None else self.free_fall[sl])

    def with_free_fall(self, up: np.ndarray, fps: float) -> FitTargets:
        """These targets with `free_fall` from their contact weights (flight: 1 - the largest) on observed frames;
        up: (3,) the world's unit up vector. Unchanged without contacts."""
        if self.contacts is None:
            return self
        observed = self.weight_2d.any(axis=1) | self.weight_3d.any(axis=1)
        flight = np.where(observed, 1.0 - self.contacts.max(axis=1, initial=0.0), 0.0)
        second = np.zeros((len(flight), 3))  # second[t]: the path's second difference about frame t - 1
        second[2:] = -GRAVITY / fps**2 * flight[1:-1, None] * up
        return dataclasses.replace(self, free_fall=np.cumsum(np.cumsum(second, axis=0), axis=0))


@dataclass
class FitResult:
    qpos: np.ndarray  # (T, nq)
    iterations: int
    cost: float
    signals: list[np.ndarray] | None = None  # fit_frames: the temporal signals' values (T, n) at qpos


def running_frames(root_xy: np.ndarray, on_feet: np.ndarray, fps: float, leg_length: float) -> np.ndarray:
    """(T,) bool: frames where the body runs: its root's net travel along the floor over RUNNING_STRIDE s centred
    on the frame (shorter at the clip's ends) is faster than the walk-run transition sqrt(WALK_RUN_FROUDE g leg),
    and each half of that stride (a step) holds a frame with a foot in contact; a half that the clip's start or
    end cuts short may hold none (its step is not seen), but not both.
    root_xy: (T, 2) m, the root's position along the floor; on_feet: (T,) bool, a foot labelled in contact;
    fps: frames per second; leg_length: m, hip height."""
    T = len(root_xy)
    half = max(1, round(RUNNING_STRIDE * fps / 2))
    first = np.clip(np.arange(T) - half, 0, T - 1)
    last = np.clip(np.arange(T) + half, 0, T - 1)
    travel = np.linalg.norm(root_xy[last] - root_xy[first], axis=1)
    fast = travel * fps / np.maximum(last - first, 1) > np.sqrt(WALK_RUN_FROUDE * GRAVITY * leg_length)
    stances = np.concatenate([[0], np.cumsum(on_feet)])  # stances[b] - stances[a]: frames a .. b - 1 on feet
    frames = np.arange(T)
    before = (stances[frames + 1] > stances[first]) | (frames - half < 0)
    after = (stances[last + 1] > stances[frames]) | (frames + half > T - 1)
    return fast & before & after & (stances[last + 1] > stances[first])


class KinematicFitter:
    """Evaluates the energy of eq. (3) and minimises it. Holds preallocated MuJoCo data; one per thread."""

    def __init__(self, body: BodyModel, camera: Camera, settings: FitSettings, fps: float, causal: bool = False,
                 unwrap_angles: bool = False):
        """causal: the fitter of an online stream (`fit_frames` with a fixed past); above 30 fps its temporal
        terms follow the causal filter's law in seconds instead of the whole-clip fit's (see below).
        unwrap_angles: the joint-angle velocity term differences rotation vectors unwrapped along time (see
        `_angle_signal`)."""
        self.body, self.camera, self.settings = body, camera, settings
        self.unwrap_angles = unwrap_angles
        self.model = body.mujoco_model()
        self.data = mujoco.MjData(self.model)
        self.site_ids = np.array([self.model.site(n).id for n in body.point_names])
        self.marker_points = body.point_index([b for _, b in MARKERS])
        self.joint_points = body.point_index(JOINT_NAMES)
        self.pelvis_point = body.point_index(["pelvis"])[0]
        com_weights = kin.center_of_mass_point_weights(body)
        self.com_points = body.point_index(list(com_weights))
        self.com_weights = np.array(list(com_weights.values()))
        self.contact_points = body.point_index(CONTACT_POINTS)
        tab = kin.tables(body)
        self.ball_vadr = tab.vadr[tab.ball_bodies]
        self.ball_qidx = tab.qadr[tab.ball_bodies][:, None] + np.arange(4)
        self.neutral_inverse_left = quat_left_matrix(quat_conjugate(neutral_qpos(body)[self.ball_qidx]))
        n_ball, M = len(self.ball_vadr), len(self.marker_points)
        self.frame_rows = 5 * M + 3 * n_ball + len(tab.hinge_bodies)
        # Where each prior block's 9 entries go in the frame Jacobian.
        k, i, j = np.meshgrid(np.arange(n_ball), np.arange(3), np.arange(3), indexing="ij")
        self.prior_rows = (5 * M + 3 * k + i).ravel()
        self.prior_cols = (self.ball_vadr[k] + j).ravel()

        self.hinge_qadr, self.hinge_vadr = tab.qadr[tab.hinge_bodies], tab.vadr[tab.hinge_bodies]
        self.hinge_limits = np.array([body.bodies[b].limit for b in tab.hinge_bodies])
        # Joint angles of the angle-velocity term: ball joints' rotation vectors, then hinge angles.
        self.angle_columns = np.concatenate([(self.ball_vadr[:, None] + np.arange(3)).ravel(), self.hinge_vadr])
        # Temporal terms are stated at 30 fps: rescale finite differences to keep their meaning per second. A causal
        # fit with its past fixed is a filter, whose rise time and overshoot in seconds stay those of 30 fps above
        # it when the acceleration weight grows as fps^2, the velocity weights as fps, and each frame's own terms
        # also pull towards the last pose, weighted (fps / 30 - 1) times as much (`data_damping`): the damping
        # that 30 fps frames get from their coarse steps (docs/decisions/fit-frame-rate.md, "The online fit above 30
        # fps").
        rate = fps / STATED_FPS
        self.fps, self.causal = fps, causal
        if causal and rate > 1.0:
            self.accel_scale, self.velocity_scale, self.data_damping = rate, float(np.sqrt(rate)), rate - 1.0
        else:
            self.accel_scale, self.velocity_scale, self.data_damping = rate ** 2, rate, 0.0
        self._jac = np.zeros((len(self.site_ids), 3, body.nv))

    # ---- kinematics through MuJoCo's C functions --------------------------------------------------------
    def evaluate(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """qpos (T, nq) -> points (T, P, 3) and their Jacobians (T, P, 3, nv)."""
        m, d = self.model, self.data
        T, P = len(qpos), len(self.site_ids)
        points = np.empty((T, P, 3))
        jac = np.empty((T, P, 3, self.body.nv))
        for t in range(T):
            d.qpos[:] = qpos[t]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            for k, site in enumerate(self.site_ids):
                mujoco.mj_jacSite(m, d, jac[t, k], None, site)
            points[t] = d.site_xpos[self.site_ids]
        return points, jac

    def integrate(self, qpos: np.ndarray, step: np.ndarray) -> np.ndarray:
        """qpos (T, nq) moved by step (T, nv) on the manifold, with MuJoCo's mj_integratePos."""
        out = np.array(qpos, dtype=float)
        for t in range(len(out)):
            mujoco.mj_integratePos(self.model, out[t], step[t], 1.0)
        return out

    # ---- per-frame terms ----------------------------------------------------------------------------------
    def frame_terms(self, qpos, points, jac, targets: FitTargets) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (T, m) and Jacobians (T, m, nv) of the terms that involve one frame only.

        Written for few numpy calls: the causal fit evaluates it for one frame several times per video frame."""
        cam = self.camera
        T, nv, M = len(qpos), self.body.nv, len(self.marker_points)
        n_ball = len(self.ball_vadr)
        floor = self._active_floor(targets)
        floor_rows = 4 if floor is not None else 0
        r = np.empty((T, self.frame_rows + floor_rows))
        J = np.zeros((T, self.frame_rows + floor_rows, nv))
        mp, mj = points[:, self.marker_points], jac[:, self.marker_points]
        # Reprojection, in metres at the person's depth: r = s (K2 (x, y) / z + c - keypoint).
        if targets.weight_2d.any():
            pc = mp @ cam.R.T + cam.t
            inv_z = 1.0 / np.maximum(pc[..., 2], 1e-6)
            uv = pc[..., :2] * inv_z[..., None]
            scale = targets.weight_2d * (targets.depth[:, None] / cam.focal)  # (T, M)
            K2 = cam.K[:2, :2]
            pixel_error = uv @ K2.T + cam.K[:2, 2] - targets.keypoints  # (T, M, 2)
            scale = scale * self._robust_weight(scale[..., None] * pixel_error, self.settings.robust_2d)
            r[:, :2 * M] = (scale[..., None] * pixel_error).reshape(T, -1)
            # d(pixels) / d(world point) = K2 (R[:2] - uv R[2]) / z, scaled: (T, M, 2, 3), then through the point
            # Jacobians, written in place (these arrays are the bulk of the offline fit's memory traffic).
            d_uv = (K2 @ cam.R[:2] - (uv @ K2.T)[..., None] * cam.R[2]) * (scale * inv_z)[..., None, None]
            J[:, :2 * M] = (d_uv @ mj).reshape(T, -1, nv)
        else:  # no 2D term (the trajectory optimisation's IK): its rows are the zeros they would compute
            r[:, :2 * M] = 0.0
        # Root-relative 3D landmarks.
        offset = mp - points[:, self.pelvis_point, None] - targets.targets_3d
        w3 = targets.weight_3d * self._robust_weight(targets.weight_3d[..., None] * offset, self.settings.robust_3d)
        r[:, 2 * M:5 * M] = (w3[..., None] * offset).reshape(T, -1)
        J3 = J[:, 2 * M:5 * M].reshape(T, M, 3, nv)
        np.subtract(mj, jac[:, self.pelvis_point, None], out=J3)
        J3 *= w3[..., None, None]
        # Ball joints towards the neutral pose: residual 2 vec(q) for q the rotation away from it (the rotation
        # vector to first order, sign-fixed so that q and -q agree); its derivative along a local step is
        # q_w I + [q_v]x.
        wp = np.sqrt(self.settings.weight_prior)
        quats = qpos[:, self.ball_qidx]  # (T, n_ball, 4)
        q = (self.neutral_inverse_left @ quats[..., None])[..., 0]  # neutral^-1 * q, a linear map of q
        q *= np.where(q[..., :1] < 0, -1.0, 1.0)
        row = 5 * M
        r[:, row:row + 3 * n_ball] = (2 * wp * q[..., 1:]).reshape(T, -1)
        w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        block = np.stack([w, -z, y, z, w, -x, -y, x, w], axis=-1)  # (T, n_ball, 9), row-major 3x3
        J[:, self.prior_rows, self.prior_cols] = wp * block.reshape(T, -1)
        # Hinge limits, one-sided, rounded off within `limit_band` of the limit (see _soft_excess).
        row += 3 * n_ball
        angles = qpos[:, self.hinge_qadr]
        wl = np.sqrt(self.settings.weight_limits)
        n_hinge = len(self.hinge_vadr)
        band = self.settings.limit_band
        above, above_slope = _soft_excess(angles - self.hinge_limits[:, 1], band)
        below, below_slope = _soft_excess(self.hinge_limits[:, 0] - angles, band)
        r[:, row:row + n_hinge] = wl * (above - below)
        J[:, row + np.arange(n_hinge), self.hinge_vadr] = wl * (above_slope + below_slope)
        if floor is not None:
            self._floor_terms(r[:, row + n_hinge:], J[:, row + n_hinge:], points, jac, *floor)
        return r, J

    def _floor_terms(self, r: np.ndarray, J: np.ndarray, points: np.ndarray, jac: np.ndarray, plane: np.ndarray,
                     contacts: np.ndarray) -> None:
        """Contact position (Rempe B7) for the heel and toe sites: sqrt(w) h for a site labelled in contact (c = 1),
        h = n . x + d its height; for one that is not, sqrt(w) h too where it lies under the floor by less than
        RESTING_HEIGHT, else nothing. Written into the residual rows r (T, 4) and their Jacobians J (T, 4, nv). The
        unlabelled half is ours, as Rempe's trajectory optimisation keeps every foot on or above the floor (C.2): B7
        alone let a swinging foot dip under the floor, where the physics that tracks this motion cannot follow it. A
        free foot deeper than that stands on lower ground, which the physics flags (body.support.under_the_floor),
        and is left there (docs/decisions/b4-feet-above-floor.md)."""
        normal, offset = plane[:3], plane[3]
        height = points[:, self.contact_points] @ normal + offset  # (T, 4)
        dipping = (height < 0.0) & (height > -RESTING_HEIGHT)
        held = contacts + (1.0 - contacts) * dipping  # the sites whose height the term pulls to 0
        scale = np.sqrt(self.settings.weight_floor) * held
        r[:] = scale * height
        J[:] = scale[..., None] * (normal @ jac[:, self.contact_points])

    def _active_floor(self, targets: FitTargets) -> tuple[np.ndarray, np.ndarray] | None:
        """The floor plane (4,) and contact flags (T, 4) when the contact term applies, else None."""
        if self.settings.weight_floor > 0 and targets.floor is not None and targets.contacts is not None:
            return targets.floor, targets.contacts
        return None

    @staticmethod
    def _robust_weight(residuals: np.ndarray, threshold: float) -> np.ndarray:
        """Huber weights as iteratively reweighted least squares: markers whose residual (T, M, k) is longer
        than `threshold` metres count with weight threshold / |r| (a square root, as they scale residuals), so
        a detector's gross errors (a left/right foot swap) pull linearly, not quadratically. The weights are
        held fixed within each linearisation; 0 disables them."""
        if threshold <= 0:
            return np.ones(residuals.shape[:-1])
        norm = np.linalg.norm(residuals, axis=-1)
        return np.sqrt(np.minimum(1.0, threshold / np.maximum(norm, 1e-12)))

    def temporal_signals(self, points, jac, qpos=None, huber_frames=None) -> list[Signal]:
        """The quantities whose finite differences are penalised (Signal: values, Jacobians, coefficients of the
        difference, pair weights). Acceleration of joint positions and velocity of their depth; when their weights
        are set, velocity of the pelvis-relative joints (B2) and of the joint angles (B3, needs qpos (T, nq), with
        `_angle_pair_weights` on `huber_frames` (T,) bool, by default `self.huber_frames(qpos)`: a piece of a
        clip passes its part of the whole clip's, which knows the contacts)."""
        jp, jj = points[:, self.joint_points], jac[:, self.joint_points]
        T, nv = len(points), self.body.nv
        s = self.settings
        ws = np.sqrt(s.weight_smooth) * self.accel_scale
        wd = np.sqrt(s.weight_depth) * self.velocity_scale
        axis = self.camera.R[2]
        velocity = np.array([-1.0, 1.0])
        signals: list[Signal] = [
            (ws * jp.reshape(T, -1), ws * jj.reshape(T, -1, nv), np.array([1.0, -2.0, 1.0]), None),
            (wd * (jp @ axis), wd * (axis @ jj), velocity, None),
        ]
        if s.weight_velocity > 0:
            wv = np.sqrt(s.weight_velocity) * self.velocity_scale
            pelvis, pelvis_jac = points[:, self.pelvis_point, None], jac[:, self.pelvis_point, None]
            signals.append((wv * (jp - pelvis).reshape(T, -1), wv * (jj - pelvis_jac).reshape(T, -1, nv), velocity,
                            None))
        if s.weight_angle_velocity > 0:
            if qpos is None:
                raise ValueError("the joint-angle velocity term needs the poses (qpos)")
            frames = self.huber_frames(qpos) if huber_frames is None else huber_frames
            signals.append(self._angle_signal(qpos, np.sqrt(s.weight_angle_velocity) * self.velocity_scale, frames))
        return signals

    def _angle_signal(self, qpos: np.ndarray, weight: float, huber_frames: np.ndarray) -> Signal:
        """Joint angles (T, 3 n_ball + n_hinge): the ball joints' rotation vectors from rest (the root excluded:
        its yaw wraps round) and the hinge angles; the derivative of log(q exp(d)) along a local step d is the
        inverse right Jacobian of SO(3). The vectors jump by up to 2 pi where a joint passes a half turn, which
        keeps joints away from it as a barrier would, unless `unwrap_angles` (docs/decisions/b4-rotation-wrap.md)."""
        T, nv = len(qpos), self.body.nv
        n_ball = len(self.ball_vadr)
        rotvec = quat_log(qpos[:, self.ball_qidx])  # (T, n_ball, 3)
        if self.unwrap_angles:
            rotvec = unwrap_rotation_vectors(rotvec)
        values = np.concatenate([rotvec.reshape(T, -1), qpos[:, self.hinge_qadr]], axis=1)
        jacobians = np.zeros((T, values.shape[1], nv))
        blocks = so3_right_jacobian_inverse(rotvec)  # (T, n_ball, 3, 3)
        rows = (3 * np.arange(n_ball)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
        cols = (self.ball_vadr[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
        jacobians[:, rows, cols] = blocks
        jacobians[:, 3 * n_ball + np.arange(len(self.hinge_vadr)), self.hinge_vadr] = 1.0
        return (weight * values, weight * jacobians, np.array([-1.0, 1.0]),
                self._angle_pair_weights(values, n_ball, huber_frames))

    def huber_frames(self, qpos: np.ndarray, contacts: np.ndarray | None = None) -> np.ndarray:
        """(T,) bool: the frames of the poses qpos (T, nq) where E_ang pulls linearly on fast joints: none where
        settings.angle_speed_huber is 0 or the fit causal (an online fit holds no pair weights); with
        settings.angle_speed_huber_frames "running", those where the body runs (`running_frames` of the root's
        path along the floor, world z up, and of the contact labels (T, 4): none without them); else all."""
        if self.settings.angle_speed_huber <= 0 or self.causal:
            return np.zeros(len(qpos), bool)
        if self.settings.angle_speed_huber_frames == "all":
            return np.ones(len(qpos), bool)
        if contacts is None:
            return np.zeros(len(qpos), bool)
        return running_frames(qpos[:, :2], (contacts > 0.5).any(axis=1), self.fps, self.body.lengths.hip_height)

    def _angle_pair_weights(self, angles: np.ndarray, n_ball: int, huber_frames: np.ndarray) -> np.ndarray | None:
        """Huber weights (T - 1, n) of the joint-angle velocity term's pairs of frames, from the angles (T, n):
        rotation vectors of n_ball ball joints, then hinge angles. On pairs of two `huber_frames` (T,) bool, a
        joint turning faster than settings.angle_speed_huber (rad/s) counts with weight huber / speed (a square
        root, as the weights scale residuals), so that the term stills noise but shrinks a run's fast legs only
        linearly. None where no pair is."""
        pairs = huber_frames[:-1] & huber_frames[1:]
        if not pairs.any():
            return None
        threshold = self.settings.angle_speed_huber
        speed = np.abs(np.diff(angles, axis=0)) * self.fps  # (T - 1, n) rad/s
        T1 = len(speed)
        ball = np.linalg.norm(speed[:, :3 * n_ball].reshape(T1, n_ball, 3), axis=-1)
        per_joint = np.concatenate([np.repeat(ball, 3, axis=1), speed[:, 3 * n_ball:]], axis=1)
        weights = np.sqrt(np.minimum(1.0, threshold / np.maximum(per_joint, 1e-12)))
        return np.where(pairs[:, None], weights, 1.0)

    def contact_signals(self, points, jac, targets: FitTargets):
        """Contact velocity (Rempe B6) as a weighted temporal signal: (values (T, 12), Jacobians (T, 12, nv),
        coefficients [-1, 1], weights (T - 1, 12)); a pair of frames counts when the site is in contact in both
        (the paper weighs by the first frame's label, which also stills a foot as it lifts off). Empty without
        contacts or weight."""
        if self.settings.weight_contact_velocity <= 0 or targets.contacts is None or len(points) < 2:
            return []
        T, nv = len(points), self.body.nv
        w = np.sqrt(self.settings.weight_contact_velocity) * self.velocity_scale
        c = targets.contacts
        pair = np.repeat(np.minimum(c[:-1], c[1:]), 3, axis=1)  # (T - 1, 12)
        values = w * points[:, self.contact_points].reshape(T, -1)
        jacobians = w * jac[:, self.contact_points].reshape(T, -1, nv)
        return [(values, jacobians, np.array([-1.0, 1.0]), pair)]

    def com_signals(self, points, jac, targets: FitTargets):
        """The centre of mass's acceleration (ours) as a weighted temporal signal, its points' weighted sum
        (kinematics.center_of_mass_point_weights) less `targets.free_fall` when given: values (T, 3), Jacobians
        (T, 3, nv), coefficients [1, -2, 1], no pair weights. The fit's millimetre noise, twice differentiated, is
        the force its motion implies (docs/decisions/b4-centre-of-mass.md). Offline only; empty at weight 0."""
        if self.settings.weight_com_acceleration <= 0:
            return []
        w = np.sqrt(self.settings.weight_com_acceleration) * self.accel_scale * self.com_weights
        values = np.einsum("p,tpi->ti", w, points[:, self.com_points])
        if targets.free_fall is not None:
            values -= w.sum() * targets.free_fall
        return [(values, np.einsum("p,tpin->tin", w, jac[:, self.com_points]), np.array([1.0, -2.0, 1.0]), None)]

    # ---- offline: the whole clip -------------------------------------------------------------------------
    def _offline_system(self, qpos, targets, band=None, progress=None, scale=None):
        """Cost, gradient g (T, nv) and upper block bands H (3, T, nv, nv) of the Gauss-Newton system: H[d, t]
        is the block of frames (t, t + d). Written into `band` when given (it is overwritten), else allocated.
        `scale` (T, nv), when given, receives the diagonal of the frames' own terms (without the temporal ones):
        the Levenberg-Marquardt damping's scale (fit_offline).

        Assembled ASSEMBLY_FRAMES frames at a time: only one chunk's Jacobians are alive at once, so the memory
        beyond the band does not grow with the clip. progress(frames done) after each chunk."""
        T, nv = len(qpos), self.body.nv
        H = np.empty((3, T, nv, nv)) if band is None else band
        H[...] = 0.0
        g = np.zeros((T, nv))
        cost = 0.0
        huber_frames = self.huber_frames(qpos, targets.contacts)  # the whole clip's: a chunk's is too short to judge
        for first in range(0, T, ASSEMBLY_FRAMES):
            last = min(first + ASSEMBLY_FRAMES, T)
            cost += self._add_chunk(qpos, targets, first, last, g, H, huber_frames, scale)
            if progress:
                progress(last)
        return cost, g, H

    def _add_chunk(self, qpos, targets, first, last, g, H, huber_frames, scale=None) -> float:
        """Add to g and H the terms of frames first .. last - 1 and the temporal residuals that start there (they
        reach up to two frames further, evaluated again by the next chunk), the frames' own terms' diagonal into
        `scale` when given; returns their cost. huber_frames: (T,) bool, the whole clip's (`huber_frames`)."""
        end = min(last + TEMPORAL_REACH, len(qpos))
        window = slice(first, end)
        points, jac = self.evaluate(qpos[window])
        own = last - first
        r, J = self.frame_terms(qpos[first:last], points[:own], jac[:own], targets.frames(slice(first, last)))
        Jt = J.transpose(0, 2, 1)
        H[0, first:last] += Jt @ J
        if scale is not None:
            scale[first:last] = np.einsum("tki,tki->ti", J, J)
        g[first:last] += (Jt @ r[..., None])[..., 0]
        cost = float(np.sum(r * r))
        del r, J, Jt  # freed before the temporal terms make theirs: the chunk's peak
        F = end - first
        window_targets = targets.frames(window)
        # A signal of weight 0 (the IK's smoothness and depth) adds zeros to g and H: left out.
        signals = [(v, j, c, w) for v, j, c, w in self.temporal_signals(points, jac, qpos[window],
                                                                                  huber_frames[window])
                   if v.any() or j.any()]
        for values, jacobians, coeffs, pair_weights in (signals + self.contact_signals(points, jac, window_targets)
                                                        + self.com_signals(points, jac, window_targets)):
            K = len(coeffs)
            if K - 1 > TEMPORAL_REACH:
                raise ValueError(f"a temporal term spans {K} frames, more than TEMPORAL_REACH allows")
            n = min(own, F - K + 1)  # residuals that start in this chunk and end within the clip
            if n <= 0:
                continue
            # rho_u = w_u * sum_a c_a v_(u+a): frame s enters rho_(s-a) with c_a, so the block of frames
            # (s, s + d) is J_s^T diag(sum_a c_a c_(a+d) w_(s-a)^2) J_(s+d), one product per band.
            rho = sum(c * values[k:k + n] for k, c in enumerate(coeffs))
            squared = 1.0 if pair_weights is None else pair_weights[:n]**2
            cost += float(np.sum(squared * rho * rho))
            pull = np.zeros_like(values)
            for a in range(K):
                pull[a:a + n] += coeffs[a] * squared * rho
            transposed = jacobians.transpose(0, 2, 1)
            g[window] += (transposed @ pull[..., None])[..., 0]
            for d in range(K):
                # Without pair weights all rows of a frame weigh the same: scale the (nv, nv) products instead.
                row_weights = np.zeros((F - d,) + (() if pair_weights is None else values.shape[1:]))
                for a in range(K - d):
                    row_weights[a:a + n] += coeffs[a] * coeffs[a + d] * squared
                if pair_weights is None:
                    H[d, first:end - d] += row_weights[:, None, None] * (transposed[:F - d] @ jacobians[d:])
                else:
                    weighted = (row_weights[..., None] * jacobians[:F - d]).transpose(0, 2, 1)
                    H[d, first:end - d] += weighted @ jacobians[d:]
        return cost

    @staticmethod
    def _solve_banded(g, H, damping, scale):
        """Solve (H + damping * diag(scale, every frame) + 1e-9 I) dx = -g; H holds the upper block bands (3, T,
        nv, nv) and is overwritten by the factor; scale (nv,) per degree of freedom.

        Pairs of frames make the system block-tridiagonal, solved by block Cholesky in O(T). Each pair's factor
        and its coupling to the next pair take the place of the pair's own blocks of H (three each), so the
        solve needs no memory that grows with the clip beyond H."""
        y = KinematicFitter._banded_forward(g, H, damping * scale)
        return KinematicFitter._banded_backward(H, y, g.shape[0], g.shape[1])

    @staticmethod
    def _banded_forward(g: np.ndarray, H: np.ndarray, damping: np.ndarray) -> np.ndarray:
        """_solve_banded's factorisation, pair by pair, with the forward substitution: y (T nv,) with L y = -g,
        damping (nv,) added to every frame's diagonal; H then holds each pair's factor and its coupling W to the
        pair before."""
        T, nv = g.shape
        pairs = (T + 1) // 2
        diagonal = np.arange(2 * nv)
        b = -g.ravel()
        y = np.empty(T * nv)
        previous = np.empty((0, 0))  # the factor of the pair before (read from the second pair on)
        for s_ in range(pairs):
            a = 2 * s_
            m = min(2, T - a)  # frames in the pair: the last one of an odd clip is alone
            n = m * nv
            D = np.empty((n, n))
            D[:nv, :nv] = H[0, a]
            if m == 2:
                D[:nv, nv:] = H[1, a]
                D[nv:, :nv] = H[1, a].T
                D[nv:, nv:] = H[0, a + 1]
            D[diagonal[:n], diagonal[:n]] += np.tile(damping, m) + 1e-9
            rhs = b[a * nv:(a + m) * nv]
            if s_:
                # The coupling of the pair before (frames a - 2, a - 1) to this one: frames two apart and the
                # neighbours a - 1, a; the block of frames a - 2 and a + 1 is zero, and stays so in W.
                C = np.zeros((2 * nv, n))
                C[:nv, :nv] = H[2, a - 2]
                C[nv:, :nv] = H[1, a - 1]
                if m == 2:
                    C[nv:, nv:] = H[2, a - 1]
                W = _triangular_solve(previous, C)
                H[2, a - 2], H[1, a - 1] = W[:nv, :nv], W[nv:, :nv]
                if m == 2:
                    H[2, a - 1] = W[nv:, nv:]
                D -= W.T @ W
                rhs = rhs - W.T @ y[(a - 2) * nv:a * nv]
            # LAPACK called directly: the loop is sequential, and scipy's checking wrappers cost as much as the
            # 80 x 80 factorisations themselves.
            L, info = dpotrf(D, lower=1, clean=1)
            if info:
                raise LinAlgError("the damped normal matrix is not positive definite")
            H[0, a] = L[:nv, :nv]
            if m == 2:
                H[1, a], H[0, a + 1] = L[nv:, :nv], L[nv:, nv:]
            y[a * nv:(a + m) * nv] = _triangular_solve(L, rhs)
            previous = L
        return y

    @staticmethod
    def _banded_backward(H: np.ndarray, y: np.ndarray, T: int, nv: int) -> np.ndarray:
        """_solve_banded's backward substitution through the factors _banded_forward left in H: x (T, nv)."""
        pairs = (T + 1) // 2
        x = np.empty(T * nv)
        L = np.zeros((2 * nv, 2 * nv))  # lower triangle read only
        for s_ in range(pairs - 1, -1, -1):
            a = 2 * s_
            m = min(2, T - a)
            n = m * nv
            L[:nv, :nv] = H[0, a]
            if m == 2:
                L[nv:, :nv], L[nv:, nv:] = H[1, a], H[0, a + 1]
            rhs = y[a * nv:(a + m) * nv]
            if s_ + 1 < pairs:  # minus W x of the next pair, W's blocks stored over the coupling's
                after = x[(a + 2) * nv:(a + 4) * nv]
                coupled = np.concatenate([H[2, a] @ after[:nv], H[1, a + 1] @ after[:nv]])
                if len(after) > nv:
                    coupled[nv:] += H[2, a + 1] @ after[nv:]
                rhs = rhs - coupled
            x[a * nv:(a + m) * nv] = _triangular_solve(L[:n, :n], rhs, transpose=1)
        return x.reshape(T, nv)

    def planned_passes(self, frames: int) -> int:
        """The frame passes fit_offline plans for a clip of `frames` frames (its progress's first total)."""
        return frames * (self.settings.offline_iterations + 1)

    def fit_offline(self, qpos_init: np.ndarray, targets: FitTargets,
                    progress: Callable[[int, int], None] | None = None) -> FitResult:
        """Minimise the energy over all frames jointly, starting from qpos_init (T, nq), by Levenberg-Marquardt on
        the manifold: stops after `offline_iterations` accepted steps or when a step lowers the cost by less than
        LM_TOLERANCE (relative).

        The Gauss-Newton bands are the fit's one buffer that grows with the clip (3 nv^2 doubles a frame); the
        solve factors them in place, so after a rejected step the system at the current poses is assembled
        again (the same numbers) rather than kept in a second copy. progress(frame passes done, planned): a
        frame pass is one frame's terms and Jacobians evaluated once; one pass over the clip to start and one
        per step tried (two more for a rejected one)."""
        T, nv = len(qpos_init), self.body.nv
        iterations = self.settings.offline_iterations
        band = np.empty((3, T, nv, nv))
        # Marquardt's damping per degree of freedom, scaled by the frames' own terms (their diagonal's mean over
        # the clip) alone: the temporal terms' diagonal grows with the frame rate (the acceleration's as fps^4)
        # while the smooth motions they barely resist do not, so scaled by it the damping held back the fit at 60
        # and 120 fps; per frame, frames without observations went undamped (docs/decisions/fit-frame-rate.md).
        scale = np.empty((T, nv))
        passed = 0

        def system_at(q, passes_left):
            nonlocal passed
            planned = passed + T * passes_left

            def report(frames):
                # A pass's end is reported by the next pass or by the fit's end: a rejected last step adds
                # passes, and a display must not close before they are done.
                if frames < T and progress is not None:  # only handed on with a progress display
                    progress(passed + frames, planned)

            cost, g, _ = self._offline_system(q, targets, band, report if progress else None, scale)
            passed += T
            return cost, g

        q = np.array(qpos_init, dtype=float)
        cost, g = system_at(q, iterations + 1)
        damping, factored, done = OFFLINE_DAMPING, False, 0
        for done in range(1, iterations + 1):
            improved = False
            while damping < 1e8:
                if factored:  # the band holds a factor or a rejected step's system: the same one again
                    cost, g = system_at(q, iterations - done + 2)
                factored = True
                try:
                    step = self._solve_banded(g, band, damping, scale.mean(axis=0))
                except (LinAlgError, np.linalg.LinAlgError):
                    damping *= 10
                    continue
                q_new = self.integrate(q, step)
                cost_new, g_new = system_at(q_new, iterations - done + 1)
                if cost_new < cost:
                    decrease = (cost - cost_new) / max(cost, 1e-12)
                    q, cost, g, factored, improved = q_new, cost_new, g_new, False, True
                    damping = max(damping / 3, 1e-7)
                    break
                damping *= 4
            if not improved or decrease < LM_TOLERANCE:
                break
        if progress:
            progress(passed, passed)
        return FitResult(q, done, cost)

    # ---- online: frames each with its own fixed past ---------------------------------------------------
    def _frames_system(self, qpos, targets, history, anchor=None):
        """K independent frames, each with its past fixed: costs (K,), gradients g (K, nv), Gauss-Newton
        matrices H (K, nv, nv) and the temporal signals' values (K, n) at qpos. history: per temporal signal
        the values of the frames before (K, h, n), oldest first, or None; anchor: the frames' own residuals at
        the last pose (K, m), pulled towards with weight `data_damping`, or None."""
        points, jac = self.evaluate(qpos)
        r, J = self.frame_terms(qpos, points, jac, targets)
        Jt = J.transpose(0, 2, 1)
        H = Jt @ J
        g = (Jt @ r[..., None])[..., 0]
        cost = np.einsum("km,km->k", r, r)
        if anchor is not None:
            moved = r - anchor
            H *= 1.0 + self.data_damping
            g += self.data_damping * (Jt @ moved[..., None])[..., 0]
            cost += self.data_damping * np.einsum("km,km->k", moved, moved)
        signals = self.temporal_signals(points, jac, qpos)
        for (values, jacobians, coeffs, _), past in zip(signals, history or [None] * len(signals), strict=True):
            if past is None or past.shape[1] < len(coeffs) - 1:
                continue
            rho = coeffs[-1] * values + np.einsum("j,kjn->kn", coeffs[:-1], past[:, 1 - len(coeffs):])
            Jc = coeffs[-1] * jacobians
            Jct = Jc.transpose(0, 2, 1)
            H += Jct @ Jc
            g += (Jct @ rho[..., None])[..., 0]
            cost += np.einsum("kn,kn->k", rho, rho)
        return cost, g, H, [values for values, _, _, _ in signals]

    def fit_frames(self, qpos_init: np.ndarray, targets: FitTargets, history, iterations: int,
                   tolerance: float = LM_TOLERANCE, damping_increase: float = 4.0,
                   last: np.ndarray | None = None) -> FitResult:
        """Fit K independent frames side by side (qpos_init (K, nq), targets of K frames), each with its own
        past (history: per temporal signal (K, h, n) values of the frames already fitted, or None): one
        Levenberg-Marquardt per frame, batched, each frame with its own damping and stopping as
        `fit_offline` does, its damping multiplied by `damping_increase` after a rejected step. The
        online fit is K = 1; the offline fit's initial pass runs many causal streams at once. Returns the poses,
        the most steps any frame took, the summed cost and the temporal signals' values at the result. last:
        the last fitted poses (K, nq), which a causal fitter above 30 fps pulls towards (`data_damping`)."""
        q = np.array(qpos_init, dtype=float)
        K, nv = len(q), self.body.nv
        anchor = None
        if last is not None and self.data_damping > 0:
            anchor = self.frame_terms(last, *self.evaluate(last), targets)[0]
        cost, g, H, signals = self._frames_system(q, targets, history, anchor)
        damping = np.full(K, ONLINE_DAMPING)
        steps = np.zeros(K, dtype=int)
        active = np.ones(K, dtype=bool)
        diagonal = np.arange(nv)
        while active.any():
            rows = np.flatnonzero(active)
            every = len(rows) == K  # no copies of the targets and the past while every frame is still going
            A = H[rows]
            A[:, diagonal, diagonal] *= 1 + damping[rows, None]
            A[:, diagonal, diagonal] += 1e-9
            try:
                step = np.linalg.solve(A, -g[rows, :, None])[..., 0]
            except np.linalg.LinAlgError:
                damping[rows] *= 10
                active[rows] = damping[rows] < 1e8
                continue
            q_new = self.integrate(q[rows], step)
            past = history if every or history is None else [None if h is None else h[rows] for h in history]
            c_new, g_new, H_new, s_new = self._frames_system(
                q_new, targets if every else targets.frames(rows), past,
                anchor if every or anchor is None else anchor[rows])
            better = c_new < cost[rows]
            won, lost = rows[better], rows[~better]
            decrease = (cost[won] - c_new[better]) / np.maximum(cost[won], 1e-12)
            if every and better.all():
                q, cost, g, H, signals = q_new, c_new, g_new, H_new, s_new
            else:
                q[won], cost[won], g[won], H[won] = q_new[better], c_new[better], g_new[better], H_new[better]
                for values, new in zip(signals, s_new, strict=True):
                    values[won] = new[better]
            steps[won] += 1
            damping[won] = np.maximum(damping[won] / 3, 1e-7)
            damping[lost] *= damping_increase
            active[won] = (steps[won] < iterations) & (decrease >= tolerance)
            active[lost] = damping[lost] < 1e8
        return FitResult(q, int(steps.max()), float(cost.sum()), signals)

    def signal_values(self, qpos: np.ndarray) -> list[np.ndarray]:
        """The temporal signals' values at fitted frames (for a causal fit's history). The contact velocity term
        is offline only: the online fit does not use it."""
        points, jac = self.evaluate(qpos)
        return [values for values, _, _, _ in self.temporal_signals(points, jac, qpos)]


def _soft_excess(excess: np.ndarray, band: float) -> tuple[np.ndarray, np.ndarray]:
    """How far a joint is beyond its limit (excess > 0 beyond it), rounded off: max(excess, 0) outside
    |excess| < band, (excess + band)^2 / (4 band) within it (equal in value and slope at both ends). Returns the
    value and its derivative. With the kink (band 0) a Gauss-Newton step sees no limit until it has crossed one
    and its cost jumps; with the band the limit pushes back as a joint nears it."""
    if band <= 0:
        return np.maximum(excess, 0.0), (excess > 0).astype(float)
    reach = np.maximum(excess + band, 0.0)
    outside = excess >= band
    return np.where(outside, excess, reach**2 / (4 * band)), np.where(outside, 1.0, reach / (2 * band))


def _triangular_solve(L: np.ndarray, b: np.ndarray, transpose: int = 0) -> np.ndarray:
    """L^-1 b (or L^-T b) for a lower triangular L (n, n) and b (n,) or (n, k)."""
    x, info = dtrtrs(L, b, lower=1, trans=transpose)
    if info:
        raise LinAlgError("singular triangular factor")
    return x


def root_orientation(targets_3d: np.ndarray) -> np.ndarray:
    """(M, 3) root-relative marker targets -> (3, 3) pelvis orientation (x forward, y left, z up)."""
    idx = {b: i for i, (_, b) in enumerate(MARKERS)}
    left = (targets_3d[idx["left_hip"]] - targets_3d[idx["right_hip"]]
            + targets_3d[idx["left_shoulder"]] - targets_3d[idx["right_shoulder"]])
    up = 0.5 * (targets_3d[idx["left_shoulder"]] + targets_3d[idx["right_shoulder"]])
    y = left / max(np.linalg.norm(left), 1e-9)
    z = up - np.dot(up, y) * y
    z /= max(np.linalg.norm(z), 1e-9)
    R = np.stack([np.cross(y, z), y, z], axis=1)
    # Hips and shoulders unseen (zero or NaN targets): no orientation to read, start upright
    return R if np.isfinite(R).all() and np.linalg.det(R) > 0.5 else np.eye(3)


def neutral_qpos(body: BodyModel) -> np.ndarray:
    """(nq,) standing straight with the arms hanging 80 degrees down from the T-pose: the pose prior's centre."""
    q = body.rest_qpos.copy()
    for side, sign in (("left", 1.0), ("right", -1.0)):
        a = body.qpos_address[body.joint_index[f"{side}_shoulder"]]
        angle = np.radians(80) * sign
        q[a:a + 4] = [np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]
    return q


def initial_qpos(body: BodyModel, camera: Camera, targets: FitTargets, frame: int) -> np.ndarray:
    """A starting pose for one frame: the neutral pose, pelvis oriented from hips and shoulders, placed on the
    camera ray of the hip midpoint at the estimated depth. (1, nq)

    Where the frame does not show them (weight 0: another detector's file, a frame with no torso), the
    orientation comes from the nearest frame whose hips and shoulders are seen, else facing the camera upright;
    the ray from the frame's hips, else from the middle of its seen keypoints, else from the image centre."""
    q = neutral_qpos(body)
    idx = {b: i for i, (_, b) in enumerate(MARKERS)}
    torso = [idx[n] for n in ("left_hip", "right_hip", "left_shoulder", "right_shoulder")]
    seen_3d = np.flatnonzero((targets.weight_3d[:, torso] > 0).all(axis=1))
    if len(seen_3d):
        q[3:7] = matrix_to_quat(root_orientation(targets.targets_3d[seen_3d[np.argmin(np.abs(seen_3d - frame))]]))
    else:
        forward, up = -camera.R[2], -camera.R[1]  # towards the camera; the camera's up, in the world
        q[3:7] = matrix_to_quat(np.stack([forward, np.cross(up, forward), up], axis=1))
    seen = targets.weight_3d[frame] > 0  # seen at all: the 2D weight is 0 below the confidence threshold too
    hips = [idx["left_hip"], idx["right_hip"]]
    if seen[hips].all():
        centre = 0.5 * (targets.keypoints[frame, hips[0]] + targets.keypoints[frame, hips[1]])
    elif seen.any():
        centre = targets.keypoints[frame, seen].mean(axis=0)
    else:
        centre = camera.K[:2, 2]
    ray = np.linalg.solve(camera.K, np.append(centre, 1.0))
    q[0:3] = camera.R.T @ (ray * targets.depth[frame] - camera.t)
    return q[None]
