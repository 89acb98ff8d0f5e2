"""A :class:`~hyperarm_tasks.runner.Robot` over the mock's simulation, without ROS.

For core tests and experiments: the runner drives ``hyperarm_driver.mock.JointSim`` (the
robot and its work cell) and its ``Camera`` directly, in simulated time, exactly as the
task node drives the mock over topics (commands rejected by the simulation are recorded as
a driver refusal, as the mock logs them).
"""
from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

import numpy as np

from hyperarm_driver.mock.camera import Camera
from hyperarm_driver.mock.config import MockConfig, load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.mock.world import BlockState
from hyperarm_control.testing import wrap_postures

from .perception import DetectionBuffer, camera_pose, matrix_to_quat

__all__ = ["SimRobot", "ForceSimRobot", "work_cell", "wrap_postures", "stall_driver"]


def work_cell(seed: int, hole_radius: float | None = None,
              destination: Sequence[float] | None = None) -> MockConfig:
    """The mock's default work cell with its imperfections and camera noise drawn from
    ``seed``; optionally the block's ``hole_radius`` (m) and the destination peg's ``xy``
    (m) changed."""
    base = load_mock_config()
    spec = base.world.spec            # the shared work-cell schema (hyperarm_description.world)
    if hole_radius is not None:
        spec = dataclasses.replace(spec, block=dataclasses.replace(
            spec.block, hole_radius=hole_radius))
    if destination is not None:
        spec = dataclasses.replace(spec, pegs=tuple(
            dataclasses.replace(p, xy=tuple(destination)) if p.name == "destination" else p
            for p in spec.pegs))
    return dataclasses.replace(
        base, world=dataclasses.replace(base.world, spec=spec),
        imperfections=dataclasses.replace(base.imperfections, seed=seed),
        camera=dataclasses.replace(base.camera, seed=seed))


class SimRobot:
    """Simulated robot stepping ``dt`` s per simulation step."""

    def __init__(self, sim: JointSim, dt: float = 0.01, cancel_at: float | None = None) -> None:
        self.sim, self.dt = sim, dt
        pose = camera_pose(sim.desc)
        self.camera = Camera(sim.cfg.camera, pose)
        self.detections = DetectionBuffer(pose)
        self._cam = pose
        self._inv_cam = np.linalg.inv(pose)
        self.cancel_at = cancel_at
        self.refused: str | None = None
        self.logs: list[tuple[str, str]] = []
        self.commands: list[tuple[float, dict, dict | None]] = []
        self.camera_on = True
        self.held = 0
        self.given: dict[str, np.ndarray] = {}    # object poses "from the goal"
        #: objects the camera does not see while the block is held (a camera the hand
        #: hides them from, e.g. looking down on the block in the gripper)
        self.hidden_while_held: set[str] = set()
        #: m: the hand hides an object from the (fixed, overhead) camera while tool0 is within
        #: this horizontal distance of each of the object's ``hide_points`` and above it (0:
        #: never), as the wrist hides the block's tab and the peg tiles from the rendered
        #: camera; ``hide_points``: object -> points (m, object frame) that show it, e.g. its
        #: markers' centres (default: the object's origin)
        self.hand_hides = 0.0
        self.hide_points: dict[str, list[np.ndarray]] = {}
        self.hidden_frames = 0    # frames in which the hand hid something
        self.at_time: list[tuple[float, object]] = []   # (sim time, fn(sim)) to inject events

    def now(self) -> float:
        return self.sim.time

    def sleep(self, seconds: float) -> None:
        for _ in range(max(1, int(round(seconds / self.dt)))):
            self.sim.step(self.dt)
            while self.at_time and self.sim.time >= self.at_time[0][0]:
                self.at_time.pop(0)[1](self.sim)
            for frame in self.camera.step(self.sim.time, self.sim.truth):
                if self.camera_on:
                    names, poses = frame.names, frame.detected
                    if self.hidden_while_held and self.sim.world.state is BlockState.HELD:
                        keep = [i for i, n in enumerate(names) if n not in self.hidden_while_held]
                        names, poses = [names[i] for i in keep], [poses[i] for i in keep]
                    if self.hand_hides > 0.0:
                        names, poses = self._not_under_the_hand(frame, names, poses)
                    self.detections.add(frame.stamp, names, poses)

    def _not_under_the_hand(self, frame, names, poses):
        """(The hand where it is when the frame is delivered, its latency later.)"""
        tool = self.sim.tool_pose()[:3, 3]
        truth = dict(zip(frame.names, frame.truth))
        keep = []
        for name, pose in zip(names, poses):
            obj = self._cam @ truth[name]              # camera_link -> root
            points = [obj[:3, :3] @ np.asarray(p) + obj[:3, 3]
                      for p in self.hide_points.get(name, [np.zeros(3)])]
            if all(np.linalg.norm(tool[:2] - xyz[:2]) <= self.hand_hides
                   and tool[2] >= xyz[2] - 0.01 for xyz in points):
                continue
            keep.append((name, pose))
        if len(keep) < len(names):
            self.hidden_frames += 1
        return [n for n, _ in keep], [p for _, p in keep]

    def cancel_requested(self) -> bool:
        return self.cancel_at is not None and self.sim.time >= self.cancel_at

    def joint_positions(self) -> dict[str, float]:
        s = self.sim.state()
        return dict(zip(self.sim.names, s.position.tolist()))

    def joint_efforts(self) -> dict[str, float]:
        s = self.sim.state()
        return dict(zip(self.sim.names, s.effort.tolist()))

    def joint_states_age(self) -> float:
        return 0.0                  # the simulation's state is always the present one

    def command(self, positions: Mapping[str, float],
                efforts: Mapping[str, float] | None = None) -> None:
        names = list(positions)
        eff = [float(efforts.get(n, 0.0)) for n in names] if efforts else ()
        self.commands.append((self.sim.time, dict(positions), dict(efforts) if efforts else None))
        try:
            self.sim.command(names, [float(positions[n]) for n in names], eff)
        except Exception as exc:  # noqa: BLE001 - the mock's refusal, reported as the driver's
            self.refused = str(exc)

    def hold(self) -> str | None:
        """The drivers' hold service: every servo where it is, the gripper's grip kept."""
        self.sim.hold_keeping_grip([n for n in self.sim.names if n != self.sim.rail])
        self.held += 1
        return None

    def fault(self, joints: Sequence[str]) -> str | None:
        if self.refused:
            return self.refused
        errs = [f"{n}: {self.sim.errors[n]}" for n in joints if n in self.sim.errors]
        if errs:
            return "hardware error " + ", ".join(errs)
        off = [n for n, on in zip(self.sim.names, self.sim.torque_enabled()) if not on and n in joints]
        return f"torque off on {', '.join(off)}" if off else None

    def given_object(self, name: str):
        return self.given.get(name)

    def wrench(self):
        return None

    def force_available(self) -> bool:
        return False

    def set_force_control(self, enabled: bool) -> str | None:
        return "no force node in the simulation"

    def send_hybrid(self, goal) -> None:
        raise RuntimeError("no force node in the simulation")

    def force_passive(self) -> tuple[str, str] | None:
        return None

    def home_rail(self) -> str | None:
        self.sim.home_rail()
        return None

    def rail_homed(self) -> bool | None:
        return self.sim.homed

    def log(self, level: str, message: str) -> None:
        self.logs.append((level, message))


class ForceSimRobot(SimRobot):
    """:class:`SimRobot` with the force node's core in the loop: each simulation step the
    controller gets the joint state (chain order) and its command goes to the simulation,
    as ``hybrid_force`` does over topics, with the node's event handling (a stale passive
    calls the driver's hold, any other passive holds the arm joints with one position
    command). ``late``: (start, end) windows of simulated time in which no joint state
    reaches the controller (a loaded machine: it goes passive on stale states).
    ``overtaken``: (start, end) windows of simulated time in which a command reaches the
    simulation only together with the next one, which replaces it (a loaded machine, or a
    driver that writes the latest command per cycle: the first is never applied).
    ``params``: the node's parameters (name: value, as ``hybrid_force`` declares them)
    that differ from their defaults."""

    def __init__(self, sim: JointSim, kin, dt: float = 0.01,
                 late: Sequence[tuple[float, float]] = (), output: str = "position",
                 params: Mapping[str, object] | None = None,
                 overtaken: Sequence[tuple[float, float]] = (), **kw) -> None:
        from hyperarm_control.force.controller import ForceController
        from hyperarm_control.force.law import HybridLaw
        from hyperarm_control.force.parameters import PARAMETERS, build
        from hyperarm_control.force.wrench import WrenchEstimator
        super().__init__(sim, dt, **kw)
        values = {name: v[0] for name, v in PARAMETERS.items()}
        values["output"] = output
        values.update(params or {})
        law_cfg, est_cfg, ctl_cfg = build(values)
        law = HybridLaw(kin, law_cfg)
        self.ctl = ForceController(law, WrenchEstimator(law.na, est_cfg), None, ctl_cfg)
        self.kin = kin
        self.late = list(late)
        self.overtaken = list(overtaken)
        self.overtaken_commands = 0         # commands never applied (``overtaken``)
        self.passive: tuple[str, str] | None = None
        self.events: list[tuple[float, str, str]] = []    # (time, kind, message)
        self._chain = [self.sim.names.index(n) for n in self.ctl.names]
        self._arm = [self.sim.names.index(n) for n in self.ctl.arm_names]

    def _is_late(self) -> bool:
        return any(a <= self.sim.time < b for a, b in self.late)

    def _handle(self, event) -> None:
        if event is None:
            return
        self.events.append((self.sim.time, event.kind, event.message))
        from hyperarm_control.force.controller import Mode
        if self.ctl.mode is Mode.PASSIVE:
            self.passive = (event.kind, event.message)
        if event.hold and event.kind == "stale":
            SimRobot.hold(self)
        elif event.hold:
            q = self.sim.state().position
            self.sim.command(self.ctl.arm_names, [float(q[i]) for i in self._arm])

    def sleep(self, seconds: float) -> None:
        for _ in range(max(1, int(round(seconds / self.dt)))):
            super().sleep(self.dt)
            now = self.sim.time
            if not self._is_late():
                s = self.sim.state()
                out, event = self.ctl.step(now, s.position[self._chain], s.velocity[self._chain],
                                           s.effort[self._arm])
                self._handle(event)
                lost = out.efforts is not None and any(a <= now < b
                                                       for a, b in self.overtaken)
                self.overtaken_commands += lost
                if out.efforts is not None and not lost:
                    if out.positions is not None:
                        self.sim.command(out.names, out.positions, out.efforts)
                    else:
                        self.sim.command(out.names, (), out.efforts)
            self._handle(self.ctl.check_stale(now))

    def joint_states_age(self) -> float:
        return self.dt if self._is_late() else 0.0

    def force_available(self) -> bool:
        return True

    def set_force_control(self, enabled: bool) -> str | None:
        from hyperarm_control.force.errors import ForceError
        try:
            event = self.ctl.enable(enabled, self.sim.time)
        except ForceError as exc:
            return f"cannot enable: {exc}"
        self.passive = None
        self._handle(event)
        return None

    def send_hybrid(self, goal) -> None:
        _, event = self.ctl.on_goal(self.kin.root_frame, goal.xyz, matrix_to_quat(goal.rotation),
                                    goal.stiffness, goal.force_axes, goal.wrench)
        self._handle(event)

    def force_passive(self) -> tuple[str, str] | None:
        return self.passive


def stall_driver(robot: SimRobot, on_applied=None, every: float = 2.0, at: float = 1.0,
                 length: float = 0.3, stop_at: float | None = None) -> None:
    """Make ``robot``'s driver stall ``length`` s in every ``every`` s (from ``at`` s into
    each): it applies no command and publishes no joint_states meanwhile, then takes the
    newest goal, as a loaded machine's driver does. From ``stop_at`` s on (if given) it
    publishes joint_states no more. ``on_applied(positions)`` is called with every command
    the driver applies."""
    real = robot.command

    def stalled() -> bool:
        return at <= robot.now() % every < at + length

    def command(positions, efforts=None):
        if not stalled():
            real(positions, efforts)
            if on_applied is not None:
                on_applied(positions)
    robot.command = command

    def age() -> float:
        if stop_at is not None and robot.now() >= stop_at:
            return robot.now() - stop_at
        return robot.now() % every - at if stalled() else 0.0
    robot.joint_states_age = age
