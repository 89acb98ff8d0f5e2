"""The shipped figure-8 task on the mock's simulation, for host compensation's figures and
tests (no ROS).

- :func:`figure8_task`: the shipped figure-8 task (``track_path``) run by the task runner
  on the simulation of :mod:`hyperarm_control.benchmark.host_sim` (repeatability 0), as
  shipped or with ``redundancy: min_reaction``; the base moment over the figure-8's
  traversal, from the measured joint states (:class:`~hyperarm_control.host.ReactionModel`,
  what ``host_compensation`` publishes on ``base_reaction``).

Units: s, m, rad, N, N·m.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from hyperarm_description.model import load_description
from hyperarm_control.benchmark.host_sim import ARM, _sim
from hyperarm_control.host import AccelerationEstimator, ReactionModel
from hyperarm_ik.kinematics import Kinematics

__all__ = ["figure8_task"]


def figure8_task(redundancy: str | None = None) -> dict[str, object]:
    """The figure-8 task on the simulation (see the module doc): ``t`` (s), ``moment``
    (N·m, norm of the base moment) over the traversal, and the task's ``metrics``."""
    from hyperarm_tasks.runner import Runner
    from hyperarm_tasks.sequence import find_task, load_task
    from hyperarm_tasks.testing import SimRobot

    desc = load_description(variant="arm")
    kin = Kinematics(variant="arm")
    text = find_task("figure8").read_text()
    if redundancy is not None:
        text = text.replace("    min_reached:", f"    redundancy: {redundancy}\n    min_reached:",
                            1)
    sim = _sim(desc)
    robot = SimRobot(sim)
    phase = {"now": ""}
    trace: list[tuple[float, np.ndarray, np.ndarray]] = []
    idx = [sim.names.index(n) for n in ARM]
    step = robot.sleep

    def sleep(seconds: float) -> None:      # record the measured states while tracking
        step(seconds)
        if phase["now"] == "tracking":
            s = sim.state()
            trace.append((s.stamp, s.position[idx].copy(), s.velocity[idx].copy()))

    robot.sleep = sleep
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "figure8_host.yaml").write_text(text)
        task = load_task("figure8_host", desc, [tmp])
    result = Runner(robot, kin, task, on_feedback=lambda fb: phase.update(now=fb.phase)).run()
    if not result.success:
        raise RuntimeError(f"figure-8 task failed: {result.message}")
    reaction, accel = ReactionModel(kin), AccelerationEstimator()
    moment = [float(np.linalg.norm(reaction.wrench(q, dq, accel.update(t, dq))[3:]))
              for t, q, dq in trace]
    t = np.array([tr[0] for tr in trace])
    return {"t": t - t[0], "moment": np.array(moment), "metrics": dict(result.metrics)}
