"""Planted feet (issue 17, point 4).

Online (`FootPlanter`; docs/decisions/physics-online-feet.md): the kinematic target's held feet are moved onto
where the character planted them, as Rempe's B.4 foot-locks the kinematics offline before PhysCap tracks them. A
fit's foot keeps wandering during a contact; tracked as it is, the PD drags the planted foot after it (the contact
constraint then lets it slide at slide_speed). Causal: each frame uses the character's state and the contacts it
held up to then.

Offline (`plant_held_feet`; docs/decisions/physics-planted-feet.md): after the tracker, knowing the whole clip,
each held contact point of its output is put on one spot, where its kinematic input stood the foot, as Rempe's final
inverse kinematics stands the body on the optimised contacts.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..body import kinematics as kin
from ..body.ik import solve_points
from ..body.model import CONTACT_POINTS, BodyModel
from ..contacts.flights import EASE_TIME, edge_easing
from ..motion import valid_runs

LEG_JOINTS = ("hip", "knee", "ankle")  # the joints bent to move a foot, per side
LEG_POINTS = ("left_knee", "left_ankle", "left_heel", "left_toe", "right_knee", "right_ankle", "right_heel",
              "right_toe")  # the points those joints move: the offline planting's goals
DAMPING = 0.01  # m: damped least squares' lambda; a leg straight enough to be singular moves its foot along it
FADED = 1e-4  # m: a shift below this is gone
CONTACT_WEIGHT = 30.0  # a planted point's pull to its spot against a joint's to its simulated place (both in m)
IK_ITERATIONS = 4  # Gauss-Newton steps of the offline planting: shifts of centimetres converge to well under a mm


def leg_dofs(model: mujoco.MjModel) -> list[tuple[list[int], np.ndarray]]:
    """Per side (left, right): the indices of its contact points (into CONTACT_POINTS) and the degrees of freedom
    of its hip, knee and ankle (LEG_JOINTS) in the MuJoCo model."""
    legs = []
    for side in ("left", "right"):
        dofs: list[int] = []
        for name in LEG_JOINTS:
            joint = model.joint(f"{side}_{name}").id
            count = 3 if model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_BALL else 1
            dofs += range(model.jnt_dofadr[joint], model.jnt_dofadr[joint] + count)
        legs.append(([j for j, name in enumerate(CONTACT_POINTS) if name.startswith(side)], np.array(dofs)))
    return legs


class LegMover:
    """The kinematics of one pose and the damped least squares step of each leg (hip, knee, ankle) that moves its
    foot's contact points: what both planters share."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.data = mujoco.MjData(model)  # the kinematics of the pose being moved
        self.sites = [model.site(name).id for name in CONTACT_POINTS]
        self._jacobians = np.zeros((6, model.nv))  # a foot's two contact points' Jacobians, stacked
        self._damping = [DAMPING * DAMPING * np.eye(3 * k) for k in range(3)]  # per number of points moved
        self._step = np.zeros(model.nv)
        self.legs = leg_dofs(model)  # per side: the contact points' indices (into CONTACT_POINTS) and the DOFs

    def contact_points(self, q: np.ndarray) -> np.ndarray:
        """(4, 3) m: the contact points of the pose q (nq,), whose kinematics `moved` then uses."""
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)  # the Jacobians' reference point
        return self.data.site_xpos[self.sites].copy()

    def moved(self, q: np.ndarray, shifts: list[list[float]]) -> np.ndarray:
        """A copy of q (nq,) with each leg bent so that its contact points move by shifts (4 x [x, y], m) along
        the floor, their heights kept, to first order; contact_points(q) must be the last call."""
        target = q.copy()
        moving_legs = [(moving, dofs) for points, dofs in self.legs
                       if (moving := [j for j in points if shifts[j] != [0.0, 0.0]])]
        if moving_legs:
            self._step[:] = 0.0
            for moving, dofs in moving_legs:
                self._step[dofs] = self._leg_step(moving, dofs, shifts)
            mujoco.mj_integratePos(self.model, target, self._step, 1.0)
        return target

    def _leg_step(self, points: list[int], dofs: np.ndarray, shifts: list[list[float]]) -> np.ndarray:
        """(len(dofs),) rad: the leg's joint step that moves the contact points `points` (of one foot) by their
        shifts along the floor and keeps their heights, to first order (damped least squares, DAMPING)."""
        error: list[float] = []
        for k, j in enumerate(points):
            mujoco.mj_jacSite(self.model, self.data, self._jacobians[3 * k:3 * k + 3], None, self.sites[j])
            error += (*shifts[j], 0.0)
        jacobian = self._jacobians[:len(error), dofs]
        normal = jacobian @ jacobian.T + self._damping[len(points)]
        mujoco.mju_cholFactor(normal, 0.0)  # positive definite: the damping bounds it from below
        weights = np.zeros(len(error))
        mujoco.mju_cholSolve(weights, normal, np.array(error))
        return jacobian.T @ weights


class FootPlanter(LegMover):
    """The target's held contact points moved along the floor onto their planted points (plant). A point is
    planted where the character holds it when the contact begins; the planted point then follows the fit's with
    the time constant follow_time (s), and never lies farther than reach (m; None: any distance) from it, so that
    a fit's foot that moves on is followed at slide_speed instead of being let go at once. Once the point is no
    longer held, its shift fades with the same time constant, so that the target does not jump. The shift bends
    the target's hip, knee and ankle (one damped least squares step on the contact points, their heights kept):
    the root and the upper body stay the fit's."""

    def __init__(self, model: mujoco.MjModel, fps: float, follow_time: float, reach: float | None):
        super().__init__(model)
        self.keep = math.exp(-1.0 / (fps * follow_time))  # share of the shift left after a frame
        self.reach = math.inf if reach is None else reach
        # The per-frame bookkeeping of four points runs on Python floats: numpy's cost per call outweighs the
        # arithmetic (as in physcap.PhysCapTracker).
        self.shifts = [[0.0, 0.0] for _ in range(4)]  # m, each point's shift along the floor (planted minus fitted)
        self.holding = [False, False, False, False]  # the points planted in the last frame
        self._fitted = [[0.0, 0.0] for _ in range(4)]  # m, the last frame's fitted points along the floor

    def shifted(self, fitted_points: np.ndarray) -> np.ndarray:
        """(4, 3) m: fitted_points (4, 3) m moved by the last frame's shifts, where the target's points would lie."""
        points = fitted_points.copy()
        points[:, :2] += self.shifts
        return points

    def plant(self, q_kin: np.ndarray, fitted_points: np.ndarray, character_points: np.ndarray,
              held: list[bool]) -> np.ndarray:
        """q_kin (nq,) with its legs bent so that its held contact points (flags of four) lie on their planted
        points, and points let go keep their fading shift. fitted_points (4, 3) m: q_kin's, from
        contact_points(q_kin), which must be the last call; character_points (4, 3) m: the character's. A copy."""
        keep, reach = self.keep, self.reach
        fitted_xy = [point[:2] for point in fitted_points.tolist()]
        for j, ((x, y), (last_x, last_y), (char_x, char_y, _)) in enumerate(zip(
                fitted_xy, self._fitted, character_points.tolist(), strict=True)):
            shift_x, shift_y = self.shifts[j]
            if held[j] and not self.holding[j]:  # planted where the character holds it: no jump in the target
                shift_x, shift_y = char_x - x, char_y - y
            elif held[j]:  # the planted point stays, but for its share following the fit's point
                shift_x, shift_y = keep * (shift_x + last_x - x), keep * (shift_y + last_y - y)
                length = math.hypot(shift_x, shift_y)
                if length > reach:
                    shift_x, shift_y = shift_x * reach / length, shift_y * reach / length
            else:
                shift_x, shift_y = keep * shift_x, keep * shift_y
                if max(abs(shift_x), abs(shift_y)) < FADED:
                    shift_x = shift_y = 0.0
            self.shifts[j] = [shift_x, shift_y]
        self.holding, self._fitted = list(held), fitted_xy
        return self.moved(q_kin, self.shifts)


class OutputPlanter(LegMover):
    """The online physics' output with its held contact points standing still (plant), causally: a point is put
    where it touched down, and that spot follows it only once it strays farther than reach (m) (the forward half
    of `leashed_spots`); a point no longer held keeps its shift, fading with the time constant EASE_TIME, so that
    the output does not jump. The whole body moves by the mean shift of the held points (followed with the same
    time constant), the legs bend for the rest (one damped least squares step): bending the legs alone held the
    feet under a pelvis that the online fit places less well, and cost twice the accuracy
    (docs/decisions/physics-planted-feet.md). The simulation's own state is not touched."""

    def __init__(self, model: mujoco.MjModel, fps: float, reach: float):
        super().__init__(model)
        self.reach = reach
        self.keep = math.exp(-1.0 / (fps * EASE_TIME))  # share of a let-go point's shift left after a frame
        self.spots: list[list[float] | None] = [None, None, None, None]  # m along the floor, while held
        self.shifts = [[0.0, 0.0] for _ in range(4)]  # m, spot minus simulated point
        self.body_shift = [0.0, 0.0]  # m along the floor, the whole output's

    def plant(self, pose: np.ndarray, held: np.ndarray, frozen: bool) -> np.ndarray:
        """A copy of the output pose (nq,) with the points held (flags of four) on their spots; in a frozen frame
        (handed back to the kinematics) nothing is held and the shifts fade."""
        points = self.contact_points(pose).tolist()
        for j, (x, y, _) in enumerate(points):
            spot = self.spots[j]
            if held[j] and not frozen:
                if spot is None:
                    spot = [x, y]
                away_x, away_y = x - spot[0], y - spot[1]
                distance = math.hypot(away_x, away_y)
                if distance > self.reach:
                    share = 1.0 - self.reach / distance
                    spot = [spot[0] + share * away_x, spot[1] + share * away_y]
                self.spots[j], self.shifts[j] = spot, [spot[0] - x, spot[1] - y]
            else:
                shift_x, shift_y = self.keep * self.shifts[j][0], self.keep * self.shifts[j][1]
                if max(abs(shift_x), abs(shift_y)) < FADED:
                    shift_x = shift_y = 0.0
                self.spots[j], self.shifts[j] = None, [shift_x, shift_y]
        holding = [self.shifts[j] for j in range(4) if held[j] and not frozen]
        goal_x = sum(shift[0] for shift in holding) / len(holding) if holding else 0.0
        goal_y = sum(shift[1] for shift in holding) / len(holding) if holding else 0.0
        body_x, body_y = self.body_shift
        body_x, body_y = goal_x + self.keep * (body_x - goal_x), goal_y + self.keep * (body_y - goal_y)
        self.body_shift = [body_x, body_y]
        # A point held or still easing off bends its leg by what the body's shift leaves; the others go with it.
        legs = [[x - body_x, y - body_y] if [x, y] != [0.0, 0.0] or (held[j] and not frozen) else [0.0, 0.0]
                for j, (x, y) in enumerate(self.shifts)]
        planted = self.moved(pose, legs)
        planted[0] += body_x
        planted[1] += body_y
        return planted


def leashed_spots(points: np.ndarray, reach: float) -> np.ndarray:
    """(n, 2) m: the spots along the floor on which one contact's points (n, 2) m are planted: the mean of a spot
    led from the first point and one led back from the last, each staying put until its point strays farther than
    `reach` and then dragged to that distance. A contact drifting at most `reach` stands on one spot (the middle
    of its path); one drifting farther slides along its path less the reach (half the reach is taken off at each
    end)."""
    def led(path: np.ndarray) -> np.ndarray:
        spots, spot = np.empty_like(path), path[0].copy()
        for t, point in enumerate(path):
            away = point - spot
            distance = math.hypot(*away)
            if distance > reach:
                spot += away * (1.0 - reach / distance)
            spots[t] = spot
        return spots

    return 0.5 * (led(points) + led(points[::-1])[::-1])


def plant_held_feet(body: BodyModel, qpos: np.ndarray, contacts: np.ndarray, fps: float, reach: float,
                    frozen: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(T, nq): the offline physics' motion qpos (T, nq) with each contact point held (contacts (T, 4), the
    physics' own) moved along the floor onto its spot, easing on and off over EASE_TIME; the legs bent for it (hip,
    knee, ankle; knees and ankles pulled to their simulated places, body/ik.py), the frames `frozen` (T,) bool (no
    person, or handed back to the kinematics) left as they are. The tracker lets a held point slip at slide_speed
    (eq. 9) and the output crept along the floor (docs/decisions/physics-planted-feet.md); knowing the whole clip,
    each contact can stand still. A contact's spot is the leashed spot (`leashed_spots`, reach m) of its simulated
    path, moved by the median over the contact of how far `reference` (T, nq), the kinematic motion the physics
    tracked, puts the point from the pelvis beyond where qpos does (along the floor): the foot stands where the
    input put it relative to the body, not where the tracker's landing overshot, and still only where the physics
    holds it (docs/decisions/physics-planted-feet.md). Its height stays the simulated one, which already rests on
    the floor or rolls off it. The forces stay the simulation's."""
    frozen = np.asarray(frozen, bool)
    held = np.asarray(contacts, bool) & ~frozen[:, None]
    feet, legs = body.point_index(CONTACT_POINTS), body.point_index(LEG_POINTS)
    simulated = kin.forward_kinematics(body, qpos).points
    kinematic = kin.forward_kinematics(body, reference).points
    pelvis = body.point_index(("pelvis",))[0]
    points = simulated[:, feet]
    # (T, 4, 2) m: each contact point relative to the pelvis along the floor, the input's minus the output's
    misplaced = ((kinematic[:, feet, :2] - kinematic[:, pelvis, None, :2])
                 - (points[..., :2] - simulated[:, pelvis, None, :2]))
    shifts = np.zeros_like(points)
    for k in range(len(CONTACT_POINTS)):
        for start, end in valid_runs(held[:, k]):
            spots = leashed_spots(points[start:end, k, :2], reach) + np.median(misplaced[start:end, k], axis=0)
            shifts[start:end, k, :2] = spots - points[start:end, k, :2]
    # Beside a contact a point eases by a share of the shift at its edge.
    blend, edges = edge_easing(held, fps)
    shifts = blend[..., None] * shifts[np.maximum(edges, 0), np.arange(len(CONTACT_POINTS))]
    solved = blend.any(axis=1) & ~frozen
    if not solved.any():
        return np.array(qpos, dtype=float)
    goal = simulated[solved][:, legs]
    columns = [LEG_POINTS.index(name) for name in CONTACT_POINTS]
    goal[:, columns] += shifts[solved]
    weights = np.ones(goal.shape[:2])
    weights[:, columns] += (CONTACT_WEIGHT - 1.0) * blend[solved]
    dofs = np.concatenate([leg for _, leg in leg_dofs(body.mujoco_model())])
    planted = np.array(qpos, dtype=float)
    planted[solved] = solve_points(body, qpos[solved], legs, goal, weights, feet, IK_ITERATIONS, dofs)
    return planted
