"""End-to-end tier of hybrid_force's 'torque' output at its transitions (issue 24 item 7):
the installed mock_driver and hybrid_force (``output:=torque``); the tool moves under 1 mm
within 0.6 s of the enable, compliance on, compliance off and the stop. The core tier of
the same check (the force core in the loop with the mock's simulation, no ROS) is
hyperarm_tasks/test/test_force_torque_transitions_sim.py."""
from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.qos import observer_qos, qos_for
from hyperarm_control.benchmark.force_probe import ForceProbe, MockArm
from hyperarm_ik.kinematics import Kinematics

pytestmark = [pytest.mark.e2e]

# as test_force_e2e's MOCK_PARAMS: the mock's loop can fall 0.1 s behind on a loaded 2-core
# machine (the stale rule itself is tested with its default against a scripted driver)
# on the mock's simulated time (use_sim_time), in lockstep with the mock (below)
FORCE_PARAMS = {"output": "torque", "stale_timeout": 0.5, "diagnostics_period": 0.2,
                "use_sim_time": True}
WINDOW = 0.6          # s after each transition
BOUND = 0.001         # m: issue 24 item 7


@pytest.fixture(scope="module")
def kin() -> Kinematics:
    return Kinematics(load_description())


def _postures(kin: Kinematics, seed: int, count: int) -> list[np.ndarray]:
    """Random postures drawn as the core test draws them (the same rng calls): the tool
    ahead of the base (more than 0.15 m out) and above the base's plane (z > 0.08 m)."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        q = rng.uniform(-1.2, 1.2, 9)
        q[1], q[8] = rng.uniform(0.0, 1.0), 0.0
        t = kin.forward(q)
        if t[2, 3] > 0.08 and np.linalg.norm(t[:2, 3]) > 0.15:
            out.append(q)
    return out


def _workcell_no_block(tmp_path) -> str:
    """The shipped ``workcell_no_block.yaml`` with repeatability 0 and seed 1, as the core
    test's cell (the truth is then FK of the joint states)."""
    import yaml
    from ament_index_python.packages import get_package_share_directory

    src = f"{get_package_share_directory('hyperarm_driver')}/config/workcell_no_block.yaml"
    data = yaml.safe_load(open(src, encoding="utf-8"))
    data["imperfections"].update({"repeatability": 0.0, "seed": 1})
    out = tmp_path / "workcell_no_block.yaml"
    out.write_text(yaml.safe_dump(data), encoding="utf-8")
    return str(out)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Truth:
    """The mock's ``debug/tool_pose_truth`` (tool0 in world) recorded by the probe's node:
    [(header stamp s, position (3,))]."""

    def __init__(self, probe: ForceProbe) -> None:
        from geometry_msgs.msg import PoseStamped

        self.probe = probe
        self.samples: list[tuple[float, np.ndarray]] = []
        # every sample counts: a busy probe must not lose any (the contract's depth 10 did,
        # a fresh-clone run got 24 of 60 in 0.6 s)
        probe.node.create_subscription(PoseStamped, contract.TOOL_POSE_TRUTH, self._on,
                                       observer_qos(contract.TOOL_POSE_TRUTH))

    def _on(self, msg) -> None:
        p = msg.pose.position
        with self.probe.lock:
            self.samples.append((_stamp(msg), np.array([p.x, p.y, p.z])))

    def last(self) -> tuple[float, np.ndarray] | None:
        with self.probe.lock:
            return self.samples[-1] if self.samples else None

    def between(self, t0: float, t1: float) -> np.ndarray:
        with self.probe.lock:
            return np.array([p for (t, p) in self.samples if t0 <= t <= t1]).reshape(-1, 3)


def _now(probe: ForceProbe) -> float:
    return probe.node.get_clock().now().nanoseconds * 1e-9


def _to_posture(probe: ForceProbe, arm: MockArm, truth: Truth, wait_for, q) -> None:
    """joint_command (position) to ``q`` (sent again while waiting: a first command can be
    lost while discovery completes), then at rest: the true tool within 0.02 mm over 0.5 s."""
    wait_for(lambda: (probe.command(arm.arm, q),
                      np.abs(arm.q_now() - q).max() < 2e-3)[1], 15.0, period=0.2,
             what=f"posture {np.round(q, 3).tolist()}")

    def still() -> bool:
        last = truth.last()
        if last is None:
            return False
        xs = truth.between(last[0] - 0.5, last[0])
        return len(xs) >= 30 and float(np.ptp(xs, axis=0).max()) < 2e-5
    wait_for(still, 10.0, period=0.05, what="the tool at rest")


def _excursion(probe: ForceProbe, arm: MockArm, truth: Truth, wait_for, action,
               name: str) -> tuple[float, float]:
    """Run ``action`` (a service call; must succeed) and return the largest distance (m) of
    the tool from its pose just before it, within WINDOW s of the call: of the mock's
    true tool (debug/tool_pose_truth, by its stamps) and of FK of the measured joints
    (joint_states, by their stamps)."""
    t0, p0 = truth.last()
    with probe.lock:
        q0_msg = probe.states[-1][1]
    t_call = _now(probe)
    res = action()
    assert res.success, (name, res.message)
    wait_for(lambda: truth.last()[0] > t_call + WINDOW + 0.05, 10.0,
             what=f"{WINDOW} s of tool truth after {name}")
    xs = truth.between(t_call, t_call + WINDOW)
    assert len(xs) >= 0.5 * WINDOW * 100, f"{name}: {len(xs)} truth samples in {WINDOW} s"
    true_max = float(np.linalg.norm(xs - p0, axis=1).max())
    with probe.lock:
        msgs = [m for _, m in probe.states if t_call <= _stamp(m) <= t_call + WINDOW]
    idx = [list(q0_msg.name).index(n) for n in arm.arm]
    fk0 = arm.kin.forward(np.array(q0_msg.position)[idx])[:3, 3]
    fk = np.array([arm.kin.forward(np.array(m.position)[idx])[:3, 3] for m in msgs])
    fk_max = float(np.linalg.norm(fk - fk0, axis=1).max()) if len(fk) else float("nan")
    return true_max, fk_max


def _stop(proc) -> None:
    """SIGINT to a launched executable; it must exit cleanly (as the launch fixture asks
    at teardown)."""
    proc.proc.send_signal(signal.SIGINT)
    proc.proc.wait(timeout=10.0)
    assert proc.proc.returncode in (0, -signal.SIGINT), proc.output()[-2000:]


@pytest.mark.slow
def test_torque_output_transitions_move_the_tool_under_1_mm(launch, rclpy_context, executor,
                                                            wait_for, tmp_path, kin):
    """From 2 random postures (seed 1, drawn as the core test draws them: the first two of
    its seed 1) in the shipped cell without the block (repeatability 0, seed 1), the arm
    put there by joint_command and at rest, hybrid_force (``output:=torque``, the posture
    = that start posture, a node per posture: ``posture`` is read-only) is enabled, then
    compliance on, compliance off, then disabled, each 0.6 s after the one before: the
    mock's true tool moves less than 1 mm within 0.6 s of each from its pose just before it,
    and hybrid_force never goes passive (diagnostics; every service call succeeds). Its
    commands are effort-only while enabled (the torque output in use). Fails with
    ``switch_gap:=0.0`` (the gap's impulse not added back: 1.04-1.10 mm at the enable)."""
    # the mock on simulated time at 1x, in lockstep (lockstep_timeout) with hybrid_force
    # once it answers the states: on a loaded machine the simulation waits for the torque
    # commands instead of running on with old ones (what a real robot never sees; the
    # torque output through ROS on a loaded machine, docs/force.md); the probe reads the
    # same clock (the truth's stamps are simulated time)
    launch("hyperarm_driver", "mock_driver",
           params={"workcell_file": _workcell_no_block(tmp_path), "diagnostics_period": 0.2,
                   "sim_speed": 1.0, "lockstep_timeout": 0.2})
    probe = ForceProbe(rclpy_context, executor, wait_for)
    from rclpy.parameter import Parameter
    probe.node.set_parameters([Parameter("use_sim_time", value=True)])
    truth = Truth(probe)
    arm = MockArm(probe, wait_for)
    arm.q_now()
    wait_for(lambda: truth.last() is not None, 20.0, what="debug/tool_pose_truth")
    results: dict[str, dict[str, tuple[float, float]]] = {}
    t_start = time.monotonic()
    for i, q in enumerate(_postures(kin, seed=1, count=2)):
        posture = "[" + ",".join(f"{v:.6f}" for v in q) + "]"
        t_launch = time.monotonic()
        hf = launch("hyperarm_control", "hybrid_force",
                    params=dict(FORCE_PARAMS, posture=posture))
        _to_posture(probe, arm, truth, wait_for, q)     # while the node starts
        # hybrid_force reading joint_states (an ee_wrench on each): enable can work
        wait_for(lambda: probe.wrench and probe.wrench[-1][0] > t_launch, 30.0,
                 what="ee_wrench (hybrid_force reading joint_states)")
        with probe.lock:
            n_status = len(probe.statuses)
        got = {}
        got["start"] = _excursion(probe, arm, truth, wait_for,
                                  lambda: probe.enable(True), "start")
        got["compliance on"] = _excursion(probe, arm, truth, wait_for,
                                          lambda: probe.compliance(True), "compliance on")
        got["compliance off"] = _excursion(probe, arm, truth, wait_for,
                                           lambda: probe.compliance(False), "compliance off")
        got["stop"] = _excursion(probe, arm, truth, wait_for,
                                 lambda: probe.enable(False), "stop")
        # the torque output in use: effort-only commands (current mode) while enabled,
        # then one arm-only position hold at the stop
        with probe.lock:
            cmds = [m for (t, m) in probe.commands if t > t_launch]
        effort_only = [m for m in cmds if list(m.effort) and not list(m.position)]
        assert len(effort_only) >= 100, f"{len(effort_only)} effort-only commands"
        shape = [(len(m.position), len(m.effort)) for m in cmds]
        assert shape[0] == (0, 9) and shape[-1] == (9, 0), shape[:3] + shape[-3:]
        key = f"posture {i} {np.round(q, 2).tolist()}"
        results[key] = got
        print(f"{key}: tool excursion (mm, truth / FK of joint_states):",
              {k: f"{a * 1e3:.3f} / {b * 1e3:.3f}" for k, (a, b) in got.items()})
        # never passive: every hybrid_force status since its start
        time.sleep(0.25)                         # a diagnostics period after the stop
        with probe.lock:
            statuses = probe.statuses[n_status:]
        modes = [st[1]["mode"] for st in statuses]
        assert modes and modes[-1] == "disabled", modes[-5:]
        passive = [st[2] for st in statuses if st[1]["mode"] == "passive"]
        assert not passive, (key, passive)
        assert "passive" not in hf.output(), hf.output()[-2000:]
        assert "Traceback" not in hf.output(), hf.output()[-2000:]
        _stop(hf)
    print(f"transitions of 2 postures in {time.monotonic() - t_start:.1f} s")
    worst = {k: max(r[k][0] for r in results.values()) for k in next(iter(results.values()))}
    print("largest true tool excursion (mm):", {k: round(v * 1e3, 3) for k, v in worst.items()})
    assert all(v < BOUND for v in worst.values()), results
