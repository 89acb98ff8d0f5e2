"""The mock's physics: MuJoCo stepping the generated model of the robot and its work cell
(no ROS, no contact code of our own).

The model is :func:`hyperarm_description.mjcf.build_model`'s, generated from the robot
description and the work cell (docs/mujoco.md); this module only puts the servos' outputs
into its actuators, steps it, and reads back joint states, actuator forces and contacts.

Actuators (one ``general`` actuator per actuated joint, changed at run time, never
rebuilt; :meth:`Physics.set_servo`):

- position class (Dynamixel position / current-based position, the PMAC's position loop):
  force = kp·(ctrl - q) - kv·q̇ within ±limit, the servo model putting its goal, the
  hidden offset, the velocity term and its feed-forward into ``ctrl``
  (:meth:`Physics.position_ctrl`);
- current: force = ctrl within ±limit (the servo model keeps ctrl on the motor's
  torque-speed line);
- off: no force.

Units: m, rad, s, N, N·m; poses are 4x4 homogeneous matrices in the root frame (the world
frame of the model).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import mujoco
import numpy as np

from hyperarm_description import mjcf
from hyperarm_description.model import RobotDescription
from hyperarm_description.world import WorldSpec

__all__ = ["Physics", "ContactPoint", "ServoKind"]

#: what a servo's actuator is (``Physics.set_servo``)
ServoKind = str   # "position" | "current" | "off"


@dataclass(frozen=True)
class ContactPoint:
    """One MuJoCo contact: the bodies' owners (``a``, ``b``: a geom's name, e.g.
    ``block_piece3``, ``peg_source``, ``capsule_link4``, ``pad_left``, ``table``), ``dist``
    (m, < 0 penetrating), ``point`` (m, world), ``force`` (N, world: what ``b`` exerts on
    ``a``)."""

    a: str
    b: str
    dist: float
    point: np.ndarray
    force: np.ndarray


_OTHER, _BLOCK, _TABLE = 0, 1, 2


def _kind(geom: str) -> int:
    return _BLOCK if geom.startswith("block_piece") else _TABLE if geom == "table" else _OTHER


class Physics:
    """MuJoCo's model and data for a description (its variant), a work cell and an
    optional host (a mocap body carrying the root, with a passive ``mount``).

    ``names`` are the actuated joints in the mock's order (rail first, arm joints, gripper);
    the arrays :attr:`q`, :attr:`qd`, :attr:`force` follow it."""

    def __init__(self, desc: RobotDescription, world: WorldSpec | None,
                 options: mjcf.PhysicsOptions, *, host: bool = False,
                 mount: mjcf.Mount | None = None) -> None:
        self.desc = desc
        self.options = options
        self.model = mjcf.build_model(desc, world, options, host=host or mount is not None,
                                      mount=mount)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.names = list(desc.all_joint_names)
        jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.names]
        self._qadr = np.array([m.jnt_qposadr[j] for j in jid])
        self._dadr = np.array([m.jnt_dofadr[j] for j in jid])
        self._act = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, n)
                              for n in self.names])
        self.mount_dofs = np.array([m.jnt_dofadr[mujoco.mj_name2id(
            m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in mjcf.MOUNT_JOINTS]) \
            if mount is not None else np.zeros(0, dtype=int)
        for a in self._act:              # the servo model sets the goal's range itself
            m.actuator_ctrllimited[a] = 0
        self.n = len(self.names)
        self._kp = np.zeros(self.n)
        self._kv = np.zeros(self.n)
        self.kind: list[ServoKind] = ["position"] * self.n
        self.body = {m.body(i).name: i for i in range(m.nbody)}
        self.tool_body = self.body[desc.tool_frame]
        self.base_body = self.body[desc.base_frame]
        self.block_body = self.body.get("block", -1)
        self.host_mocap = int(m.body_mocapid[self.body["host"]]) if "host" in self.body else -1
        if self.block_body >= 0:
            bj = m.body_jntadr[self.block_body]
            self._block_qadr = int(m.jnt_qposadr[bj])
            self._block_dadr = int(m.jnt_dofadr[bj])
        self.geom_names = [m.geom(i).name for i in range(m.ngeom)]
        self._geom_kind = np.array([_kind(name) for name in self.geom_names])
        self._force6 = np.zeros(6)
        self._bias = np.zeros(self.n)
        mujoco.mj_forward(m, self.data)

    # -- set-up -------------------------------------------------------------------------
    def set_positions(self, q: Sequence[float]) -> None:
        """Put the actuated joints at ``q`` (rad, m) at rest and recompute the state."""
        self.data.qpos[self._qadr] = q
        self.data.qvel[self._dadr] = 0.0
        self._sync_fingers()
        mujoco.mj_forward(self.model, self.data)

    def _sync_fingers(self) -> None:
        """The fingers where the gripper joint's coupling puts them."""
        m, d = self.model, self.data
        for side in ("finger_left", "finger_right"):
            e = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, side)
            j1, j2 = m.eq_obj1id[e], m.eq_obj2id[e]
            c = m.eq_data[e]
            d.qpos[m.jnt_qposadr[j1]] = c[0] + c[1] * d.qpos[m.jnt_qposadr[j2]]

    def set_friction(self, coulomb: np.ndarray, damping: np.ndarray) -> None:
        """Each actuated joint's Coulomb friction (N·m, N) and viscous damping (N·m·s/rad)."""
        self.model.dof_frictionloss[self._dadr] = coulomb
        self.model.dof_damping[self._dadr] = damping

    def set_servo(self, i: int, kind: ServoKind, limit: float, kp: float = 0.0,
                  kv: float = 0.0) -> None:
        """Joint ``i``'s actuator: ``position`` (a PD, kp, kv), ``current`` (a motor with
        its force the control: the servo model applies the torque-speed line) or ``off``, its force within
        ±``limit``."""
        a = self._act[i]
        m = self.model
        gain, bias = m.actuator_gainprm[a], m.actuator_biasprm[a]
        gain[:3] = 0.0
        bias[:3] = 0.0
        if kind == "position":
            gain[0], bias[1], bias[2] = kp, -kp, -kv
        elif kind == "current":
            gain[0] = 1.0
        else:
            limit = 0.0
        m.actuator_forcerange[a] = (-limit, limit)
        self.kind[i] = kind
        self._kp[i], self._kv[i] = kp, kv

    def set_limit(self, i: int, limit: float) -> None:
        """Joint ``i``'s actuator force limit (N·m, N), its kind unchanged."""
        if self.kind[i] != "off":
            self.model.actuator_forcerange[self._act[i]] = (-limit, limit)

    # -- stepping -----------------------------------------------------------------------
    def position_ctrl(self, goal: np.ndarray, goal_v: np.ndarray, feedforward: np.ndarray
                      ) -> np.ndarray:
        """The ``ctrl`` of a position-class actuator that makes its force
        kp·(goal - q) + kv·(goal_v - q̇) + feedforward (clamped to its limit)."""
        kp = np.where(self._kp > 0.0, self._kp, 1.0)
        return goal + (self._kv * goal_v + feedforward) / kp

    def step(self, ctrl: np.ndarray) -> None:
        """One MuJoCo step (``options.timestep`` s) with the actuators' controls ``ctrl``."""
        self.data.ctrl[self._act] = ctrl
        mujoco.mj_step(self.model, self.data)

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    @property
    def q(self) -> np.ndarray:
        """True joint positions (rad, m)."""
        return self.data.qpos[self._qadr]

    @property
    def qd(self) -> np.ndarray:
        return self.data.qvel[self._dadr]

    @property
    def force(self) -> np.ndarray:
        """Each actuator's force this step (N·m, N), after its limit."""
        return self.data.actuator_force[self._act]

    def bias(self) -> np.ndarray:
        """Gravity and velocity-product torques on the actuated joints (N·m, N) at the
        last step's state (MuJoCo's qfrc_bias)."""
        return self.data.qfrc_bias[self._dadr]

    def inertia_times(self, acc: np.ndarray) -> np.ndarray:
        """M(q)·a on the actuated joints for joint accelerations ``acc`` (others 0)."""
        vec = np.zeros(self.model.nv)
        vec[self._dadr] = acc
        out = np.zeros(self.model.nv)
        mujoco.mj_mulM(self.model, self.data, out, vec)
        return out[self._dadr]

    def joint_inertia(self, q: np.ndarray) -> np.ndarray:
        """Each actuated joint's inertia (the mass matrix's diagonal, armature included:
        kg·m², kg) at joints ``q``, the rest of the state as it is (scratch data)."""
        m = self.model
        d = mujoco.MjData(m)
        d.qpos[:] = self.data.qpos
        d.qpos[self._qadr] = q
        mujoco.mj_forward(m, d)
        out = np.zeros(len(self._dadr))
        vec, res = np.zeros(m.nv), np.zeros(m.nv)
        for k, dof in enumerate(self._dadr):
            vec[:] = 0.0
            vec[dof] = 1.0
            mujoco.mj_mulM(m, d, res, vec)
            out[k] = res[dof]
        return out

    def body_load(self, body: int, point: np.ndarray, force: np.ndarray) -> np.ndarray:
        """Torques (N·m, N) on the actuated joints that hold a ``force`` (N, world) acting at
        ``point`` (m, world) on ``body``: -Jᵀ f."""
        jacp = np.zeros((3, self.model.nv))
        mujoco.mj_jac(self.model, self.data, jacp, None, point, body)
        return -(jacp[:, self._dadr].T @ force)

    # -- poses --------------------------------------------------------------------------
    def body_pose(self, body: int) -> np.ndarray:
        t = np.eye(4)
        t[:3, :3] = self.data.xmat[body].reshape(3, 3)
        t[:3, 3] = self.data.xpos[body]
        return t

    def tool_pose(self) -> np.ndarray:
        return self.body_pose(self.tool_body)

    def block_pose(self) -> np.ndarray:
        return self.body_pose(self.block_body)

    def set_block_pose(self, pose: np.ndarray) -> None:
        """Put the block at ``pose`` at rest (a test's set-up)."""
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, pose[:3, :3].ravel())
        self.data.qpos[self._block_qadr:self._block_qadr + 3] = pose[:3, 3]
        self.data.qpos[self._block_qadr + 3:self._block_qadr + 7] = q
        self.data.qvel[self._block_dadr:self._block_dadr + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def set_host_pose(self, pose: np.ndarray) -> None:
        """The mocap host's pose (the scripted host motion)."""
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.ascontiguousarray(pose[:3, :3]).ravel())
        self.data.mocap_pos[self.host_mocap] = pose[:3, 3]
        self.data.mocap_quat[self.host_mocap] = q

    # -- contacts -----------------------------------------------------------------------
    def contacts(self, everything: bool = False) -> list[ContactPoint]:
        """The last step's contacts with their forces: those of the block with the pads,
        the pegs and the poles, and of the links with the poles; with ``everything`` (or
        while the block is held: ``held``) also the block's on the table and the rest."""
        m, d = self.model, self.data
        n = d.ncon
        if n == 0:
            return []
        geoms = d.contact.geom[:n]
        kind = self._geom_kind
        k1, k2 = kind[geoms[:, 0]], kind[geoms[:, 1]]
        if everything:
            rows = range(n)
        else:   # skip the block resting on the table (up to 4 contacts per piece)
            table_block = ((k1 == _TABLE) & (k2 == _BLOCK)) | ((k1 == _BLOCK) & (k2 == _TABLE))
            rows = np.flatnonzero(~table_block).tolist()
        out = []
        names = self.geom_names
        for k in rows:
            c = d.contact[k]
            mujoco.mj_contactForce(m, d, k, self._force6)
            # the contact frame's first row is the normal, from geom1 to geom2: the force in
            # it is what geom1 exerts on geom2
            f = c.frame.reshape(3, 3).T @ self._force6[:3]
            out.append(ContactPoint(names[c.geom2], names[c.geom1], float(c.dist),
                                    c.pos.copy(), f))
        return out

    def self_contacts(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Pairs of robot geoms (names) that touch at the chain joints ``q`` (the actuated
        joints but the gripper), checked on a scratch copy of the state."""
        m = self.model
        d = mujoco.MjData(m)
        d.qpos[:] = self.data.qpos
        d.mocap_pos[:], d.mocap_quat[:] = self.data.mocap_pos, self.data.mocap_quat
        d.qpos[self._qadr[:len(q)]] = q
        mujoco.mj_forward(m, d)
        robot = set(self.geom_names[g] for g in range(m.ngeom)
                    if self.geom_names[g].startswith(("capsule_", "rail_carriage")))
        return [(self.geom_names[c.geom1], self.geom_names[c.geom2])
                for c in d.contact[:d.ncon]
                if c.dist < 0.0 and self.geom_names[c.geom1] in robot
                and self.geom_names[c.geom2] in robot]

    def max_penetration(self) -> float:
        """Deepest penetration (m, >= 0) over the last step's contacts."""
        d = self.data
        if d.ncon == 0:
            return 0.0
        return max(0.0, -float(np.min(d.contact.dist[:d.ncon])))

