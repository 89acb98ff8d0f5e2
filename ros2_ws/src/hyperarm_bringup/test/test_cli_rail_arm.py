"""The CLI's one-shot commands against both real drivers of rail_arm, each on its emulator
(dynamixel_driver on dxl_emulator, pmac_rail_driver on pmac_emulator), 50 times in a row:
`state --once` lists every joint of the variant, `move` says "taken" only when the joints
took their goals (an independent probe sees them arrive) and exits 1 with the driver's own
words when it refuses, and the services answer every time. Each command runs in-process
through ``cli.main`` (a fresh rclpy context and DDS participant each time, as a new
`hyperarm` process has), so 50 in a row take seconds, not minutes.

On the code before the confirmation (issue 25 item 4) this fails: `move` published once ONE
subscriber had matched and said "sent", and `state` merged a 0.3 s window after the first
message, so a table could hold only the rail."""
from __future__ import annotations

import random
import re
import time
from pathlib import Path

import pytest
import yaml

from hyperarm_bringup.cli import main
from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.qos import qos_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

NS = contract.DEFAULT_NAMESPACE
RUNS = 50
CONFIG = Path(__file__).resolve().parents[1] / "config"


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


REFUSED: list[str] = []


def attempt(capsys, *argv: str) -> tuple[int, str, str]:
    """``run``, again (at most three times in a row) after a refusal that names its reason.

    On a loaded machine the emulated hardware itself can fail: the PMAC driver latches a
    watchdog trip or a lost link (issue 25 item 5) and refuses setpoints until
    rail/set_torque (or latches it during a move: `move` then says "not taken" with the
    driver's report), a servo misses a status packet. The CLI must say so (exit 1, the
    driver's words): that is not a silent loss. The latched rail fault is cleared as its
    message says. Every such refusal is listed in the test's output."""
    code, out, err = run(capsys, *argv)
    for _ in range(3):
        # refused at once, or sent and not taken while the driver reports a latched fault
        # (the link to the emulator lost under load, latched during the move)
        if not (code == 1 and ("refused" in err or "latched" in err)):
            break
        assert "taken" not in out, (out, err)
        REFUSED.append(f"{' '.join(argv)}: {err.strip()[-150:]}")
        if "latched" in err:
            assert run(capsys, "torque", "on", "--rail", "--timeout", "10")[0] == 0
        code, out, err = run(capsys, *argv)
    return code, out, err


@pytest.fixture
def rail_arm(launch, tmp_path, wait_for, rclpy_context, executor):
    """Both drivers on their emulators, and a probe node: name -> newest position."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    pmac_emu = launch("hyperarm_driver", "pmac_emulator", "--port", "0",
                      "--start-position", "2000")
    port = wait_for(lambda: re.search(r"127\.0\.0\.1:(\d+)", pmac_emu.output()), 20.0,
                    what="PMAC emulator port").group(1)
    wait_for(lambda: (tmp_path / "ctl").exists(), 20.0, what="dxl emulator control socket")
    launch("hyperarm_driver", "dynamixel_driver", params={"port": link})
    # the on-card watchdog as the rail_arm configuration sets it (issue 25 item 5)
    config = yaml.safe_load((CONFIG / "rail_arm.yaml").read_text())
    watchdog = config["/hyperarm/pmac_rail_driver"]["ros__parameters"]["watchdog_timeout"]
    launch("hyperarm_driver", "pmac_rail_driver",
           params={"port": int(port), "variant": "rail_arm", "diagnostics_period": 0.2,
                   "watchdog_timeout": float(watchdog)})
    node = rclpy.create_node("cli_probe", namespace=NS, context=rclpy_context)
    positions: dict[str, float] = {}
    diags: dict[str, dict[str, str]] = {}
    node.create_subscription(
        JointState, contract.JOINT_STATES,
        lambda m: positions.update(zip(m.name, m.position)), qos_for(contract.JOINT_STATES))
    node.create_subscription(
        DiagnosticArray, contract.DIAGNOSTICS,
        lambda m: diags.update({s.name: {kv.key: kv.value for kv in s.values}
                                for s in m.status}), qos_for(contract.DIAGNOSTICS))
    executor.add_node(node)
    wait_for(lambda: len(positions) == 11, 30.0, what="both drivers' joint_states")
    return positions, diags


# 125 commands, each with its own DDS participant: ~315 s at load average 11 on a shared
# 2-core machine (pytest's default 180 s stops it there); see the module docstring
@pytest.mark.timeout(600)
def test_one_shot_commands_confirm_or_fail_50_times(rail_arm, capsys, wait_for):
    positions, diags = rail_arm
    limits = load_description(None, "rail_arm").limits_by_name()
    joints = list(limits)
    assert joints[-1] == contract.RAIL_JOINT and len(joints) == 11

    # refusals come back with the driver's own reason, and exit 1 (torque is off at start)
    code, out, err = run(capsys, "move", "joint3=0.2", "--timeout", "10")
    assert code == 1 and "torque is off" in err and "dynamixel_driver" in err, (out, err)
    code, out, err = run(capsys, "move", "rail=0.05", "--variant", "rail_arm",
                         "--timeout", "10")
    assert code == 1 and "rail setpoint rejected" in err and "torque is off" in err, err
    assert "taken" not in out and "sent" not in out

    for argv in (("torque", "on"), ("torque", "on", "--rail"), ("home",)):
        code, out, err = run(capsys, *argv, "--timeout", "20")
        assert code == 0, (argv, err)
    wait_for(lambda: diags.get("pmac_rail_driver: rail", {}).get("homed") == "true", 30.0,
             what="the rail homed")

    rng = random.Random(25)
    start = time.monotonic()
    services = [("torque", "on"), ("torque", "on", "--rail"), ("hold",), ("hold", "--rail")]
    for i in range(RUNS):
        code, out, err = run(capsys, "state", "--once", "--variant", "rail_arm",
                             "--timeout", "10")
        assert code == 0, (i, err)
        assert [line.split()[0] for line in out.splitlines()[1:]] == joints, (i, out)

        # a goal for one arm joint, the rail, or both, drawn well inside the limits
        names = [[rng.choice(joints[:9])], [contract.RAIL_JOINT],
                 [rng.choice(joints[:9]), contract.RAIL_JOINT]][i % 3]
        goal = {}
        for n in names:
            lo, hi = limits[n]
            span = 0.4 if n != contract.RAIL_JOINT else 0.1
            mid = min(max(positions[n], lo + span), hi - span)
            goal[n] = round(mid + rng.uniform(0.3, 1.0) * span * rng.choice((-1, 1)), 4)
        code, out, err = attempt(capsys, "move", *(f"{n}={v}" for n, v in goal.items()),
                                 "--variant", "rail_arm", "--timeout", "10")
        assert code == 0 and out.startswith("taken: "), (i, goal, out, err)
        # no silent loss: the drivers' own joint_states show every goal reached
        wait_for(lambda: all(abs(positions[n] - v) < 0.01 for n, v in goal.items()), 10.0,
                 what=lambda: f"move {i} {goal} to arrive (at {[positions[n] for n in goal]})")

        if i % 2:       # and every other round one of the services (25 in all)
            argv = services[(i // 2) % len(services)]
            code, out, err = attempt(capsys, *argv, "--timeout", "10")
            assert code == 0, (i, argv, err)
    took = time.monotonic() - start
    print(f"{RUNS} rounds of state and move (and {RUNS // 2} services) in {took:.1f} s; "
          f"refused with a reason and sent again: {len(REFUSED)}", *REFUSED, sep="\n  ")
