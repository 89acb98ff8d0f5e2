"""The suite's own scheduling (ros2_ws/src/conftest.py): a test marked ``alone`` runs while
the other pytest-xdist worker runs nothing."""
from __future__ import annotations

import pytest


@pytest.mark.slow
def test_an_alone_test_overlaps_no_other(tmp_path):
    """Two xdist workers on four files: the test marked ``alone`` runs while no other test
    runs (each test records when it ran; the suite's own conftest.py)."""
    pytest.importorskip("xdist")
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    here = Path(__file__).resolve()
    shutil.copy(here.parents[2] / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "pytest.ini").write_text(
        "[pytest]\nmarkers =\n    alone: alone\n")
    body = ("import time, pytest\n"
            "def _span(name):\n"
            "    t0 = time.time(); time.sleep(0.6)\n"
            f"    open({str(tmp_path / 'spans.txt')!r}, 'a').write(f'{{name}} {{t0}} {{time.time()}}\\n')\n")
    for k in range(3):
        (tmp_path / f"test_busy{k}.py").write_text(
            body + "".join(f"def test_{k}_{i}(): _span('busy')\n" for i in range(3)))
    (tmp_path / "test_lone.py").write_text(
        body + "@pytest.mark.alone\ndef test_lone(): _span('alone')\n")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-n", "2", "--dist", "loadfile", str(tmp_path)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    spans = [line.split() for line in (tmp_path / "spans.txt").read_text().splitlines()]
    spans = [(name, float(a), float(b)) for name, a, b in spans]
    assert len(spans) == 10
    (_, a0, b0), = [s for s in spans if s[0] == "alone"]
    busy = [s for s in spans if s[0] == "busy"]
    assert all(b <= a0 or a >= b0 for _, a, b in busy), spans
    # and the other worker did run tests side by side otherwise (the run was parallel)
    assert any(a1 < b2 and a2 < b1 for i, (_, a1, b1) in enumerate(busy)
               for (_, a2, b2) in busy[i + 1:]), spans
