"""The body model: an immutable kinematic tree with segment inertias, named points and a compiled MuJoCo model.

Rest pose: a T-pose standing on the floor, facing +x, left +y, up +z. Every body frame is aligned with the
world at rest, so a joint's offset is simply the vector from its parent's joint centre (BVH-style).

Generalised coordinates follow MuJoCo: qpos = [root position (3), root quaternion w,x,y,z (4), then per joint
a quaternion (ball, 4) or an angle (hinge, 1)]; velocities have 6 for the root (linear in world, angular in the
pelvis frame), 3 per ball joint (angular, in the child body's frame) and 1 per hinge.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .anthropometry import DE_LEVA_MALE, SegmentInertia


@dataclass(frozen=True)
class SkeletonLengths:
    """Every length that shapes the skeleton, in metres. Templates and calibration produce one of these."""

    hip_width: float  # between the hip joint centres
    thigh: float  # hip to knee
    shank: float  # knee to ankle
    ankle_height: float  # ankle centre above the sole
    heel_back: float  # heel contact point behind the ankle
    toe_front: float  # toe contact point in front of the ankle
    spine_low: float  # pelvis (hip midpoint) up to the spine joint
    spine_up: float  # spine joint up to the neck (shoulder midpoint)
    shoulder_width: float  # between the shoulder joint centres
    upper_arm: float
    forearm: float
    hand_length: float  # wrist to the midpoint of the index and little-finger knuckles
    hand_width: float  # index knuckle to little-finger knuckle
    head_height: float  # neck up to the ear midpoint (head centre)
    head_top: float  # ear midpoint up to the vertex
    ear_width: float
    nose_forward: float  # nose in front of the ear midpoint
    nose_down: float  # nose below the ear midpoint
    eye_forward: float
    eye_up: float  # eyes above the ear midpoint
    eye_width: float

    @property
    def hip_height(self) -> float:
        """Sole to hip joint when standing straight."""
        return self.ankle_height + self.shank + self.thigh

    @property
    def standing_height(self) -> float:
        """Sole to vertex when standing straight."""
        return self.hip_height + self.spine_low + self.spine_up + self.head_height + self.head_top

    def scaled(self, factor: float) -> SkeletonLengths:
        return SkeletonLengths(**{k: v * factor for k, v in self.__dict__.items()})


# Proportions of body height: long bones after Drillis & Contini (1966); hip width, foot, face and hand
# offsets as MediaPipe's landmarks place them (measured on the shared videos: its hip landmarks sit wider than
# the anatomical joint centres, its heel point lies under the ankle and its ears below the nose).
TEMPLATE_RATIOS = dict(
    hip_width=0.140, thigh=0.245, shank=0.246, ankle_height=0.028, heel_back=0.000, toe_front=0.100,
    spine_low=0.058, spine_up=0.230, shoulder_width=0.200, upper_arm=0.170, forearm=0.146, hand_length=0.055,
    hand_width=0.023, head_height=0.115, head_top=0.080, ear_width=0.085, nose_forward=0.073, nose_down=-0.012,
    eye_forward=0.057, eye_up=0.031, eye_width=0.017,
)


def template_lengths(height: float = 1.70) -> SkeletonLengths:
    """A generic adult skeleton of the given standing height (metres)."""
    lengths = SkeletonLengths(**{k: v * height for k, v in TEMPLATE_RATIOS.items()})
    return lengths.scaled(height / lengths.standing_height)


@dataclass(frozen=True)
class Body:
    """One rigid segment and the joint that connects it to its parent."""

    name: str
    joint: str
    joint_type: str  # "free", "ball" or "hinge"
    parent: int  # index of the parent body, -1 for the root
    offset: np.ndarray  # (3,) joint centre relative to the parent's joint centre at rest, metres
    axis: np.ndarray | None  # (3,) hinge axis in the body frame
    limit: tuple[float, float]  # hinge: (min, max) angle; ball: (0, max rotation); radians
    mass: float  # kg
    com: np.ndarray  # (3,) centre of mass in the body frame, metres
    inertia: np.ndarray  # (3,) principal moments about the com along the body axes, kg m^2


@dataclass(frozen=True)
class Point:
    """A named point fixed to a body: a joint centre, a contact site or a landmark."""

    name: str
    body: int
    offset: np.ndarray  # (3,) in the body frame, metres


CONTACT_POINTS: tuple[str, ...] = ("left_heel", "left_toe", "right_heel", "right_toe")

# Points every result reports, in this order (DESIGN.md), followed by the face and hand landmarks.
JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "spine", "neck", "head", "left_shoulder", "left_elbow", "left_wrist", "right_shoulder",
    "right_elbow", "right_wrist", "left_hip", "left_knee", "left_ankle", "left_heel", "left_toe", "right_hip",
    "right_knee", "right_ankle", "right_heel", "right_toe",
)
LANDMARK_POINTS: tuple[str, ...] = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_index", "left_pinky", "right_index",
    "right_pinky",
)


@dataclass(frozen=True, eq=False)  # identity hash: one model, many caches keyed on it
class BodyModel:
    """Immutable body: segments, points, mass properties. Build with `build_body_model`."""

    bodies: tuple[Body, ...]
    points: tuple[Point, ...]
    lengths: SkeletonLengths
    mass: float
    height: float
    contact_radius: float = 0.02
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    # ---- layout of the generalised coordinates -------------------------------------------------------
    @cached_property
    def qpos_address(self) -> np.ndarray:
        """(B,) index of each body's joint in qpos."""
        sizes = [{"free": 7, "ball": 4, "hinge": 1}[b.joint_type] for b in self.bodies]
        return np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)

    @cached_property
    def dof_address(self) -> np.ndarray:
        """(B,) index of each body's joint in the velocity vector."""
        sizes = [{"free": 6, "ball": 3, "hinge": 1}[b.joint_type] for b in self.bodies]
        return np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)

    @property
    def nq(self) -> int:
        last = self.bodies[-1]
        return int(self.qpos_address[-1]) + {"free": 7, "ball": 4, "hinge": 1}[last.joint_type]

    @property
    def nv(self) -> int:
        last = self.bodies[-1]
        return int(self.dof_address[-1]) + {"free": 6, "ball": 3, "hinge": 1}[last.joint_type]

    @cached_property
    def point_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.points)

    def point_index(self, names) -> np.ndarray:
        lookup = {n: i for i, n in enumerate(self.point_names)}
        return np.array([lookup[n] for n in names], dtype=int)

    @cached_property
    def body_index(self) -> dict[str, int]:
        return {b.name: i for i, b in enumerate(self.bodies)}

    @cached_property
    def joint_index(self) -> dict[str, int]:
        return {b.joint: i for i, b in enumerate(self.bodies)}

    @cached_property
    def ancestors(self) -> np.ndarray:
        """(B, B) bool: ancestors[b, a] is True when body a is b or an ancestor of b."""
        result = np.zeros((len(self.bodies), len(self.bodies)), dtype=bool)
        for b in range(len(self.bodies)):
            a = b
            while a >= 0:
                result[b, a] = True
                a = self.bodies[a].parent
        return result

    @cached_property
    def dof_body(self) -> np.ndarray:
        """(nv,) the body whose joint each degree of freedom moves."""
        out = np.empty(self.nv, dtype=int)
        for i, b in enumerate(self.bodies):
            n = {"free": 6, "ball": 3, "hinge": 1}[b.joint_type]
            out[self.dof_address[i]:self.dof_address[i] + n] = i
        return out

    @cached_property
    def quaternion_addresses(self) -> np.ndarray:
        """(n,) the index in qpos of each quaternion's w: the root's (after its position), then each ball joint's."""
        return np.array([address + (3 if b.joint_type == "free" else 0)
                         for address, b in zip(self.qpos_address, self.bodies, strict=True)
                         if b.joint_type in ("free", "ball")], dtype=int)

    @cached_property
    def rest_qpos(self) -> np.ndarray:
        """(nq,) the T-pose with the soles on the floor."""
        q = np.zeros(self.nq)
        q[self.quaternion_addresses] = 1.0
        q[2] = self.lengths.hip_height
        return q

    @cached_property
    def body_masses(self) -> np.ndarray:
        return np.array([b.mass for b in self.bodies])

    def mujoco_model(self):
        """The compiled MuJoCo model (built once, then shared; treat as read-only)."""
        if "mujoco" not in self._cache:
            from .mujoco_model import compile_mujoco

            self._cache["mujoco"] = compile_mujoco(self)
        return self._cache["mujoco"]


def _inertia_along(axis: int, mass: float, length: float, inertia: SegmentInertia) -> np.ndarray:
    """Principal moments (x, y, z) for a segment whose long axis is body axis `axis` (0 x, 1 y, 2 z)."""
    long = mass * (inertia.gyration_longitudinal * length) ** 2
    sag = mass * (inertia.gyration_sagittal * length) ** 2
    trans = mass * (inertia.gyration_transverse * length) ** 2
    if axis == 2:  # upright segment: sagittal axis is x (front-back), transverse is y (left-right)
        return np.array([sag, trans, long])
    if axis == 1:  # arm along y in the T-pose
        return np.array([sag, long, trans])
    return np.array([long, trans, sag])  # foot along x


def _combine(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, com and principal moments of rigid parts (mass, com, diagonal inertia) joined into one body.

    The parts lie on one vertical line, so the combined inertia stays diagonal (parallel axis theorem)."""
    mass = float(sum(m for m, _, _ in parts))
    com = np.asarray(sum(m * c for m, c, _ in parts) / mass)
    inertia = np.zeros(3)
    for m, c, inertia_part in parts:
        d = c - com
        inertia += inertia_part + m * (np.dot(d, d) - d * d)
    return mass, com, inertia


def build_body_model(lengths: SkeletonLengths, mass: float = 70.0) -> BodyModel:
    """Assemble the body from skeleton lengths (metres) and total mass (kg), inertias after de Leva (1996)."""
    bodies = _bodies(lengths, mass)
    points = _named_points(lengths, {b.name: i for i, b in enumerate(bodies)})
    assert tuple(p.name for p in points) == JOINT_NAMES + LANDMARK_POINTS
    total = sum(b.mass for b in bodies)
    scale = mass / total  # de Leva's fractions add up to 1 to rounding; make the total exact
    bodies = [Body(b.name, b.joint, b.joint_type, b.parent, b.offset, b.axis, b.limit, b.mass * scale, b.com,
                   b.inertia * scale) for b in bodies]
    return BodyModel(tuple(bodies), tuple(points), lengths, float(mass), float(lengths.standing_height))


def _bodies(lengths: SkeletonLengths, mass: float) -> list[Body]:
    """The rigid bodies, parents first, with de Leva's mass fractions of `mass` (kg) (their sum is not exactly 1)."""
    L = lengths
    seg = DE_LEVA_MALE
    z = lambda v: np.array([0.0, 0.0, v])  # noqa: E731 - tiny local shorthand for vertical offsets
    bodies: list[Body] = []

    def add(name, joint, joint_type, parent, offset, inertial, axis=None, limit=(0.0, np.pi)):
        m, com, inertia = inertial
        bodies.append(Body(name, joint, joint_type, parent, np.asarray(offset, float),
                           None if axis is None else np.asarray(axis, float), limit, m, com, inertia))
        return len(bodies) - 1

    def segment(kind: str, length: float, direction: np.ndarray, long_axis: int, start=(0.0, 0.0, 0.0)):
        p = seg[kind]
        m = p.mass_fraction * mass
        com = np.asarray(start, float) + direction * p.com_fraction * length
        return m, com, _inertia_along(long_axis, m, length, p)

    down = z(-1.0)
    # Pelvis: de Leva's lower trunk (omphalion to hip midpoint), its com measured from the top.
    lower_trunk = L.spine_low * 1.45  # de Leva: 0.084 of stature against our 0.058
    pelvis_inertial = segment("lower_trunk", lower_trunk, down, 2, start=z(lower_trunk))
    # Torso: upper and middle trunk stacked between the spine joint and the neck.
    upper_len, middle_len = L.spine_up * 0.44, L.spine_up * 0.56
    torso_inertial = _combine([
        segment("upper_trunk", upper_len, down, 2, start=z(L.spine_up)),
        segment("middle_trunk", middle_len, down, 2, start=z(L.spine_up - upper_len)),
    ])
    head_length = L.head_height + L.head_top
    head_inertial = segment("head", head_length, down, 2, start=z(head_length))

    pelvis = add("pelvis", "root", "free", -1, np.zeros(3), pelvis_inertial)
    torso = add("torso", "spine", "ball", pelvis, z(L.spine_low), torso_inertial, limit=(0.0, np.radians(70)))
    add("head", "neck", "ball", torso, z(L.spine_up), head_inertial, limit=(0.0, np.radians(80)))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        out = np.array([0.0, sign, 0.0])
        upper = add(f"{side}_upper_arm", f"{side}_shoulder", "ball", torso,
                    np.array([0.0, sign * L.shoulder_width / 2, L.spine_up]),
                    segment("upper_arm", L.upper_arm, out, 1), limit=(0.0, np.radians(170)))
        fore = add(f"{side}_forearm", f"{side}_elbow", "hinge", upper, out * L.upper_arm,
                   segment("forearm", L.forearm, out, 1), axis=[0.0, 0.0, -sign],
                   limit=(np.radians(-5), np.radians(155)))
        add(f"{side}_hand", f"{side}_wrist", "ball", fore, out * L.forearm,
            segment("hand", L.hand_length, out, 1), limit=(0.0, np.radians(90)))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        thigh = add(f"{side}_thigh", f"{side}_hip", "ball", pelvis, np.array([0.0, sign * L.hip_width / 2, 0.0]),
                    segment("thigh", L.thigh, down, 2), limit=(0.0, np.radians(130)))
        shin = add(f"{side}_shin", f"{side}_knee", "hinge", thigh, z(-L.thigh), segment("shank", L.shank, down, 2),
                   axis=[0.0, 1.0, 0.0], limit=(np.radians(-5), np.radians(155)))
        foot_length = L.heel_back + L.toe_front
        foot_start = np.array([-L.heel_back, 0.0, -L.ankle_height / 2])
        add(f"{side}_foot", f"{side}_ankle", "ball", shin, z(-L.shank),
            segment("foot", foot_length, np.array([1.0, 0.0, 0.0]), 0, start=foot_start),
            limit=(0.0, np.radians(60)))
    return bodies


def _named_points(lengths: SkeletonLengths, index: dict[str, int]) -> list[Point]:
    """Joint centres, contact sites and landmarks on the bodies (`index`: body name -> index), in the order of
    JOINT_NAMES + LANDMARK_POINTS."""
    L = lengths
    z = lambda v: np.array([0.0, 0.0, v])  # noqa: E731 - tiny local shorthand for vertical offsets
    points: list[Point] = []

    def point(name: str, body: str, offset=(0.0, 0.0, 0.0)):
        points.append(Point(name, index[body], np.asarray(offset, float)))

    # Joint centres and contact sites, in the order of JOINT_NAMES.
    point("pelvis", "pelvis")
    point("spine", "torso")
    point("neck", "head")
    point("head", "head", z(L.head_height))
    for side in ("left", "right"):
        point(f"{side}_shoulder", f"{side}_upper_arm")
        point(f"{side}_elbow", f"{side}_forearm")
        point(f"{side}_wrist", f"{side}_hand")
    for side in ("left", "right"):
        point(f"{side}_hip", f"{side}_thigh")
        point(f"{side}_knee", f"{side}_shin")
        point(f"{side}_ankle", f"{side}_foot")
        point(f"{side}_heel", f"{side}_foot", (-L.heel_back, 0.0, -L.ankle_height))
        point(f"{side}_toe", f"{side}_foot", (L.toe_front, 0.0, -L.ankle_height))
    # Face and hand landmarks (the hand points along the arm at rest, palm down, thumb forward).
    point("nose", "head", (L.nose_forward, 0.0, L.head_height - L.nose_down))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        point(f"{side}_eye", "head", (L.eye_forward, sign * L.eye_width / 2, L.head_height + L.eye_up))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        point(f"{side}_ear", "head", (0.0, sign * L.ear_width / 2, L.head_height))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        point(f"{side}_index", f"{side}_hand", (L.hand_width / 2, sign * L.hand_length, 0.0))
        point(f"{side}_pinky", f"{side}_hand", (-L.hand_width / 2, sign * L.hand_length, 0.0))
    return points
