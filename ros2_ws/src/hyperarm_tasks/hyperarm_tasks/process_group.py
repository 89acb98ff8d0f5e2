"""Run a script that starts nodes, and stop it with its nodes at a timeout (stdlib only, so
the core tests' numpy-1.26 environment without pinocchio can import it too)."""
from __future__ import annotations

import os
import signal
import subprocess
from typing import Mapping, Sequence

__all__ = ["run_stoppable"]


def run_stoppable(cmd: Sequence[str], *, env: Mapping[str, str], timeout: float,
                  grace: float = 15.0) -> subprocess.CompletedProcess:
    """Run ``cmd`` (a script that starts nodes, e.g. run_task.sh) in a session of its own,
    output captured as text. At ``timeout`` (s) the whole process group gets Ctrl-C
    (SIGINT, as a person stops it, so the script stops its nodes), SIGKILL after ``grace``
    s, and :class:`subprocess.TimeoutExpired` is raised with the output so far.
    ``subprocess.run``'s own timeout kills only the script and leaves its nodes running."""
    proc = subprocess.Popen(list(cmd), env=dict(env), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=grace)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
        raise subprocess.TimeoutExpired(proc.args, timeout, output=out, stderr=err) from None
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
