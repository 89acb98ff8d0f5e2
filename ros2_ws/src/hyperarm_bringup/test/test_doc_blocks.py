"""Every shell block marked `<!-- runnable -->` in README.md and docs/ runs, as pasted, from
the repository root (emulators and the mock; on this test's own ROS domain): the blocks of
each document in order, in ONE shell, as a person pastes them one after the other, and no
process they started is left behind. A block fails on its first failing command (bash -e)."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[4]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
_BLOCK = re.compile(r"<!-- runnable -->\s*\n```(?:bash|sh)\n(.*?)\n```", re.S)


def blocks() -> list[tuple[str, str]]:
    out = []
    for doc in DOCS:
        text = doc.read_text()
        for i, m in enumerate(_BLOCK.finditer(text)):
            line = text[:m.start()].count("\n") + 1
            out.append((f"{doc.relative_to(ROOT)}:{line}", m.group(1)))
    return out


def test_there_are_runnable_blocks_in_readme_and_guide():
    where = {name.split(":")[0] for name, _ in blocks()}
    assert {"README.md", "docs/user-guide.md"} <= where
    # every marker is followed by a shell block (a marker the regex misses is a typo)
    for doc in DOCS:
        assert doc.read_text().count("<!-- runnable -->") == len(_BLOCK.findall(doc.read_text()))


def _session_processes(sid: int) -> list[str]:
    """'pid command' of every process still in session ``sid``."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
            fields = text[text.rindex(")") + 2:].split()
            if int(fields[3]) == sid:          # field 6 of /proc/PID/stat: the session
                cmd = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ")
                out.append(f"{stat.parent.name} {cmd.decode(errors='replace').strip()}")
        except (OSError, ValueError, IndexError):
            pass                               # gone meanwhile
    return out


def run_in_one_shell(name: str, script: str, ros_domain: int, timeout: float) -> None:
    """``script`` in one bash (-e: stop at the first failing command; -x: its trace names
    it) in a session of its own. Fails if it fails, or
    if any process it started is still alive 3 s after it ended ('no line to stop them');
    those are killed afterwards either way. Logs the blocks wrote to /tmp/hyperarm-$$ (the
    shell's PID) are shown on failure and removed."""
    # a reader's shell: the docs' own DDS settings (LOCALHOST; env.sh's profile), not the
    # tests' (conftest's TEST_DDS_ENV)
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    # output to files, not pipes: a process left behind would hold a pipe open
    with tempfile.TemporaryFile("w+") as out_f, tempfile.TemporaryFile("w+") as err_f:
        proc = subprocess.Popen(["bash", "-e", "-x", "-c", script], cwd=ROOT, env=env,
                                stdout=out_f, stderr=err_f, text=True, start_new_session=True)
        left = _wait_and_reap(proc, timeout)
        out_f.seek(0)
        err_f.seek(0)
        out, err = out_f.read(), err_f.read()
    logdir = Path(f"/tmp/hyperarm-{proc.pid}")
    logs = {p.name: p.read_text(errors="replace")[-1500:] for p in sorted(logdir.glob("*.log"))}
    shutil.rmtree(logdir, ignore_errors=True)
    assert proc.returncode == 0, (f"{name} failed:\n{out[-3000:]}\n{err[-3000:]}\n"
                                  + "\n".join(f"--- {p}:\n{t}" for p, t in logs.items()))
    assert not left, f"{name}: left running after its end: {left}"


def _wait_and_reap(proc: subprocess.Popen, timeout: float) -> list[str]:
    """Wait for the shell; then up to 3 s for what it started to end. Returns what was
    still running then; kills everything of its session either way."""
    left: list[str] = []
    try:
        proc.wait(timeout=timeout)
        deadline = time.monotonic() + 3.0
        while (left := _session_processes(proc.pid)) and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        for line in _session_processes(proc.pid):
            try:
                os.kill(int(line.split()[0]), signal.SIGKILL)
            except ProcessLookupError:
                pass
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return left


def test_a_block_that_leaves_a_process_behind_fails(ros_domain):
    """The leftover check itself: a background sleep with no stop line is found."""
    with pytest.raises(AssertionError, match="left running after its end.*sleep 30"):
        run_in_one_shell("leaky", "sleep 30 &\ntrue", ros_domain, 20)
    run_in_one_shell("tidy", "sleep 30 & pid=$!\nkill $pid; wait $pid || true", ros_domain, 20)


@pytest.mark.parametrize("doc", sorted({name.split(":")[0] for name, _ in blocks()}))
def test_blocks_pasted_in_order_into_one_shell(doc, ros_domain):
    """Every runnable block of ``doc``, in order, as a person pastes them one after the
    other into the same terminal (issue 25 item 6: jobs left by one block made the next
    block's `kill %2` hit the wrong process and its `wait` hang)."""
    parts = [f"echo '=== {name}' >&2\n{script}" for name, script in blocks()
             if name.split(":")[0] == doc]
    run_in_one_shell(doc, "\n".join(parts), ros_domain, 170.0 * len(parts))
