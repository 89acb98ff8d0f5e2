"""End-to-end: the installed soak_block_transfer stopped mid-cycle (SIGINT or SIGTERM sent to
it alone, as a supervisor or `kill` does) stops the cycle's run_task.sh first, so that its
stack (mock_driver, hybrid_force, task_node) is not left behind, and exits 130."""
from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_to_the_soak_stops_the_cycles_stack(sig, executable, ros_domain, tmp_path,
                                                    still_running):
    logs = tmp_path / "logs"
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([executable("hyperarm_tasks", "soak_block_transfer"),
                             "--cycles", "3", "--first-seed", "4", "--logs", str(logs)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    pids = logs / "seed4" / "pids"
    try:
        deadline = time.monotonic() + 60.0
        # the cycle's stack is up: its three nodes written to the pids file and running
        while time.monotonic() < deadline and len(still_running(pids.parent)
                                                  if pids.exists() else []) < 3:
            time.sleep(0.2)
        assert pids.exists() and len(still_running(pids.parent)) >= 3, "no stack came up"
        time.sleep(1.0)
        sent = time.monotonic()
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=90)
        took = time.monotonic() - sent
    except BaseException:   # the test failed: leave nothing running for the next tests
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        for line in (pids.read_text().split() if pids.exists() else [])[1::2]:
            try:
                os.kill(int(line), signal.SIGKILL)
            except (ProcessLookupError, ValueError):
                pass
        raise
    assert proc.returncode == 130, out
    assert took < 2.0, f"stopped {took:.2f} s after the signal\n{out}"   # issue 24, item 2
    assert "killing it" not in out, out          # no node SIGKILLed
    assert "interrupted in cycle 1 (seed 4)" in out, out
    assert "Traceback" not in out, out
    assert still_running(pids.parent) == []
    assert not (logs / "seed5").exists()          # no further cycle was started
