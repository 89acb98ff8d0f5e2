"""trajectory_benchmark: arm_controller's tracking and latency on the mock (issue 26).

Starts the installed ``mock_driver`` and ``arm_controller`` on a private ROS domain (or uses
running ones with ``--attach``), sends FollowJointTrajectory goals through the action and
prints:

- **tracking**: a 9-joint trajectory whose joints peak at ``--speed`` (default 0.8) of their
  velocity limits, within the acceleration limits (a raised-cosine out and back, alternate
  joints in opposite directions); the path error (desired - measured, from the action's
  feedback at every control cycle), per joint and overall, and the result. ``--plot PNG``
  draws desired and measured positions and the error;
- **latency**: from a setpoint's time (the instant the controller samples the trajectory,
  which it writes in joint_command's header stamp) to the ``joint_command`` carrying it
  arriving here, p50/p99/max over every command of the run;
- **loop**: from a joint_states message arriving here to the joint_command that the
  controller, cycling on it, sends arriving here (both measured by this probe).

Usage: ``trajectory_benchmark [--speed 0.8] [--repeats 3] [--plot docs/benchmarks/img/
arm_controller_tracking.png]``. Figures: docs/benchmarks.md."""
from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np


def _profile(q0: np.ndarray, vmax: np.ndarray, amax: np.ndarray, speed: float, n: int = 41):
    """Raised-cosine out and back: q = q0 + s A/2 (1 - cos(2 pi t / T)); peak velocity
    A pi / T = speed vmax, peak acceleration 2 (speed vmax)^2 / A <= 0.9 amax."""
    vpk = speed * vmax
    amp = np.max(2.0 * vpk ** 2 / (0.9 * amax))
    period = float(np.max(np.pi * amp / vpk))
    sign = np.where(np.arange(len(q0)) % 2, -1.0, 1.0)
    sign = np.where(q0 + sign * amp > 2.4, -1.0, np.where(q0 + sign * amp < -2.4, 1.0, sign))
    t = np.linspace(0.0, period, n)
    w = 2 * np.pi / period
    pos = [q0 + sign * amp / 2 * (1 - np.cos(w * tt)) for tt in t]
    vel = [sign * amp / 2 * w * np.sin(w * tt) for tt in t]
    vel[-1] = np.zeros_like(q0)
    return t, pos, vel, amp


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trajectory_benchmark", description=__doc__.split(
        "\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed", type=float, default=0.8,
                    help="peak joint speed as a fraction of the velocity limit (0.8)")
    ap.add_argument("--repeats", type=int, default=3, help="trajectories sent (3)")
    ap.add_argument("--rate", type=float, default=100.0, help="arm_controller rate, Hz")
    ap.add_argument("--lead", type=float, default=None,
                    help="arm_controller's command_lead, s (default: the node's)")
    ap.add_argument("--plot", type=Path, help="write the tracking plot to this PNG")
    ap.add_argument("--attach", action="store_true",
                    help="use a running mock/robot and arm_controller (ROS_DOMAIN_ID)")
    args = ap.parse_args(argv)
    if not 0 < args.speed <= 1:
        ap.error("--speed must be in (0, 1]")
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from hyperarm_description import contract
    from hyperarm_description.launcher import installed_executable
    from hyperarm_description.model import load_description
    from hyperarm_description.qos import qos_for

    from ..client import TrajectoryClient, goal_from_points

    desc = load_description(None, "arm")
    names = [j.name for j in desc.joints]
    vmax = np.array([j.velocity for j in desc.joints])
    amax = np.array([j.acceleration for j in desc.joints])
    procs = []
    domain = int(os.environ.get("ROS_DOMAIN_ID", "0"))
    if not args.attach:
        domain = random.Random().randrange(120, 230)
        env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
        for pkg, exe, extra in (("hyperarm_driver", "mock_driver", []),
                                ("hyperarm_control", "arm_controller",
                                 ["--ros-args", "-p", f"rate:={args.rate}",
                                  "-p", f"action_monitor_rate:={args.rate}",
                                  *([] if args.lead is None else
                                    ["-p", f"command_lead:={args.lead}"])])):
            procs.append(subprocess.Popen([installed_executable(pkg, exe), *extra], env=env,
                                          stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL))
    rclpy.init(domain_id=domain)
    node = rclpy.create_node("trajectory_benchmark", namespace=contract.DEFAULT_NAMESPACE)
    states: dict[str, float] = {}
    latency: list[float] = []
    loop: list[float] = []
    last_state = [None]       # arrival time of the last arm joint_states, s
    lock = threading.Lock()

    def on_command(msg: JointState) -> None:
        now = node.get_clock().now().nanoseconds * 1e-9
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        with lock:
            latency.append(now - stamp)
            if last_state[0] is not None:
                loop.append(now - last_state[0])

    def on_state(msg: JointState) -> None:
        states.update(zip(msg.name, msg.position))
        with lock:
            last_state[0] = node.get_clock().now().nanoseconds * 1e-9

    node.create_subscription(JointState, contract.JOINT_STATES, on_state,
                             qos_for(contract.JOINT_STATES))
    node.create_subscription(JointState, contract.JOINT_COMMAND, on_command,
                             qos_for(contract.JOINT_COMMAND))
    client = TrajectoryClient(node)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    code = 0
    try:
        end = time.monotonic() + 60.0
        while not (client.server_ready() and all(n in states for n in names)):
            if time.monotonic() > end:
                print("arm_controller's action or joint_states did not appear in 60 s",
                      file=sys.stderr)
                return 1
            time.sleep(0.1)
        print(f"tracking: {args.repeats} trajectories, joints peaking at "
              f"{args.speed:.0%} of their velocity limits, feedback every cycle "
              f"({args.rate:g} Hz)")
        worst = 0.0
        runs = []
        for k in range(args.repeats):
            q0 = np.array([states[n] for n in names])
            t, pos, vel, amp = _profile(q0, vmax, amax, args.speed)
            client.send(goal_from_points(names, t, pos, vel))
            if not client.wait(t[-1] + 30.0):
                print("  no result in time", file=sys.stderr)
                return 1
            status, result = client.result()
            fb = client.feedback()
            err = np.array([f.error.positions for f in fb])
            e_max = np.abs(err).max(axis=0)
            worst = max(worst, float(e_max.max()))
            runs.append((fb, t, pos))
            print(f"  run {k + 1}: {t[-1]:.2f} s, amplitude {amp:.2f} rad, status {status} "
                  f"code {result.error_code} {result.error_string!r}; path error max "
                  f"{e_max.max() * 1e3:.1f} mrad (per joint "
                  f"{', '.join(f'{x * 1e3:.1f}' for x in e_max)}), rms "
                  f"{np.sqrt(np.mean(err ** 2)) * 1e3:.1f} mrad over {len(fb)} cycles")
            if status != 4:
                code = 1
            time.sleep(0.5)
        print(f"  worst path error {worst * 1e3:.1f} mrad (target < 20 mrad)")
        with lock:
            lat = np.array(latency) * 1e3
        print(f"latency, setpoint time -> joint_command received: p50 "
              f"{np.percentile(lat, 50):.2f} ms, p99 {np.percentile(lat, 99):.2f} ms, max "
              f"{lat.max():.2f} ms over {len(lat)} commands (target p50 < 2 ms)")
        with lock:
            lp = np.array(loop) * 1e3
        if len(lp):
            print(f"loop, joint_states received -> the joint_command it caused received "
                  f"(same probe; cycle_on_joint_states): p50 {np.percentile(lp, 50):.2f} ms, "
                  f"p99 {np.percentile(lp, 99):.2f} ms over {len(lp)} commands (issue 28: "
                  "p50 < 1 ms, p99 < 2 ms)")
        if args.plot:
            _plot(args.plot, runs[-1], names)
            print(f"plot: {args.plot}")
        return code
    finally:
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


def _plot(path: Path, run, names) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fb, _t, _pos = run
    t = np.array([f.desired.time_from_start.sec + 1e-9 * f.desired.time_from_start.nanosec
                  for f in fb])
    des = np.array([f.desired.positions for f in fb])
    act = np.array([f.actual.positions for f in fb])
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for j in range(len(names)):
        line, = ax1.plot(t, des[:, j], lw=1.2, label=names[j])
        ax1.plot(t, act[:, j], "--", lw=1.0, color=line.get_color())
        ax2.plot(t, (des[:, j] - act[:, j]) * 1e3, lw=1.0, color=line.get_color())
    ax1.set_ylabel("position, rad (solid desired, dashed measured)")
    ax1.legend(ncol=5, fontsize=7)
    ax2.axhline(20, color="k", lw=0.6, ls=":")
    ax2.axhline(-20, color="k", lw=0.6, ls=":")
    ax2.set_ylabel("path error, mrad (±20 target)")
    ax2.set_xlabel("time from the goal's start, s")
    fig.suptitle("arm_controller on the mock: FollowJointTrajectory at 80 % of the velocity "
                 "limits")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)


if __name__ == "__main__":
    sys.exit(main())
