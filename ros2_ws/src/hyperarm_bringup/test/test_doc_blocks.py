"""Every shell block marked `<!-- runnable -->` in README.md and docs/ runs, as pasted, from
the repository root (emulators and the mock; on this test's own ROS domain). A block fails
on its first failing command (bash -e)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
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


@pytest.mark.parametrize("name,script", blocks(), ids=[n for n, _ in blocks()])
def test_block_runs(name, script, ros_domain):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    # -x: a failing block's trace (stderr) names the command that failed; its own session,
    # ended afterwards: a block that fails before its own cleanup (kill ...) leaves nothing
    # running (a viewer left on port 8080 would fail the next run of the viewer's block)
    proc = subprocess.Popen(["bash", "-e", "-x", "-c", script], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=170)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if proc.poll() is None:
            proc.wait()
    logs = {p: Path(p).read_text(errors="replace")[-1500:] for p in
            re.findall(r"> (/tmp/[\w.-]+\.log)", script) if Path(p).exists()}
    assert proc.returncode == 0, (f"{name} failed:\n{out[-3000:]}\n{err[-3000:]}\n"
                                  + "\n".join(f"--- {p}:\n{t}" for p, t in logs.items()))
