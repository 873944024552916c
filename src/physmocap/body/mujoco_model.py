"""Compile a BodyModel into a MuJoCo model: same tree, joints, masses and named points, plus foot collision
spheres and a floor plane at z = 0. Visual capsules carry no mass and never collide."""

from __future__ import annotations

import numpy as np

from .model import CONTACT_POINTS, BodyModel


def _vec(v) -> str:
    return " ".join(f"{x:.17g}" for x in v)


def mjcf_xml(model: BodyModel, timestep: float = 0.01) -> str:
    """The MJCF text of the model (angles in radians)."""
    children: dict[int, list[int]] = {}
    for i, b in enumerate(model.bodies):
        children.setdefault(b.parent, []).append(i)
    points_of: dict[int, list[int]] = {}
    for i, p in enumerate(model.points):
        points_of.setdefault(p.body, []).append(i)
    r = model.contact_radius

    def body_xml(i: int, depth: int) -> str:
        b = model.bodies[i]
        pad = "  " * depth
        lines = [f'{pad}<body name="{b.name}" pos="{_vec(b.offset)}">']
        if b.joint_type == "free":
            lines.append(f'{pad}  <freejoint name="{b.joint}"/>')
        elif b.joint_type == "ball":
            lines.append(f'{pad}  <joint name="{b.joint}" type="ball" limited="true" range="0 {b.limit[1]:.17g}"/>')
        else:
            lines.append(f'{pad}  <joint name="{b.joint}" type="hinge" axis="{_vec(b.axis)}" limited="true" '
                         f'range="{b.limit[0]:.17g} {b.limit[1]:.17g}"/>')
        lines.append(f'{pad}  <inertial pos="{_vec(b.com)}" mass="{b.mass:.17g}" diaginertia="{_vec(b.inertia)}"/>')
        for c in children.get(i, []):  # a bone to each child joint
            end = model.bodies[c].offset
            if np.linalg.norm(end) > 1e-6:
                lines.append(f'{pad}  <geom class="bone" type="capsule" fromto="0 0 0 {_vec(end)}"/>')
        for k in points_of.get(i, []):
            p = model.points[k]
            lines.append(f'{pad}  <site name="{p.name}" pos="{_vec(p.offset)}" size="0.01"/>')
            if p.name in CONTACT_POINTS:  # the sphere touches the floor exactly at the site
                lines.append(f'{pad}  <geom name="{p.name}_collision" class="foot" type="sphere" size="{r:.17g}" '
                             f'pos="{_vec(p.offset + np.array([0.0, 0.0, r]))}"/>')
        for c in children.get(i, []):
            lines.append(body_xml(c, depth + 1))
        lines.append(f"{pad}</body>")
        return "\n".join(lines)

    return f"""<mujoco model="physmocap_body">
  <compiler angle="radian" inertiafromgeom="false" balanceinertia="true"/>
  <option timestep="{timestep:.17g}" gravity="0 0 -9.81"/>
  <default>
    <default class="bone">
      <geom size="0.03" contype="0" conaffinity="0" group="1" mass="0" rgba="0.7 0.7 0.9 1"/>
    </default>
    <default class="foot">
      <geom contype="1" conaffinity="0" condim="3" friction="0.8" mass="0" rgba="0.9 0.4 0.3 1"/>
    </default>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05" contype="0" conaffinity="1" rgba="0.8 0.8 0.8 1"/>
    <light pos="0 0 4" dir="0 0 -1"/>
{body_xml(0, 2)}
  </worldbody>
</mujoco>
"""


def compile_mujoco(model: BodyModel, timestep: float = 0.01):
    """mujoco.MjModel compiled from the body model."""
    import mujoco

    return mujoco.MjModel.from_xml_string(mjcf_xml(model, timestep))
