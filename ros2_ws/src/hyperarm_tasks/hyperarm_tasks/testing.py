"""A :class:`~hyperarm_tasks.runner.Robot` over the mock's simulation, without ROS.

For core tests and experiments: the runner drives ``hyperarm_driver.mock.JointSim`` (the
robot and its work cell) and its ``Camera`` directly, in simulated time, exactly as the
task node drives the mock over topics (commands rejected by the simulation are recorded as
a driver refusal, as the mock logs them).
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from hyperarm_driver.mock.camera import Camera
from hyperarm_driver.mock.joint_sim import JointSim

from .perception import DetectionBuffer, camera_pose

__all__ = ["SimRobot"]


class SimRobot:
    """Simulated robot stepping ``dt`` s per simulation step."""

    def __init__(self, sim: JointSim, dt: float = 0.01, cancel_at: float | None = None) -> None:
        self.sim, self.dt = sim, dt
        pose = camera_pose(sim.desc)
        self.camera = Camera(sim.cfg.camera, pose)
        self.detections = DetectionBuffer(pose)
        self._inv_cam = np.linalg.inv(pose)
        self.cancel_at = cancel_at
        self.refused: str | None = None
        self.logs: list[tuple[str, str]] = []
        self.commands: list[tuple[float, dict, dict | None]] = []
        self.camera_on = True
        self.held = 0
        self.given: dict[str, np.ndarray] = {}    # object poses "from the goal"
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
                    self.detections.add(frame.stamp, frame.names, frame.detected)

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
        self.sim.hold()
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
