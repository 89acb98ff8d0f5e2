"""lazy_main: a signal during a node module's import is a quiet exit 0 (core tier: no rclpy).

Each case runs a fresh interpreter with a throw-away module whose import raises SIGTERM
or SIGINT at a chosen place, as a user's Ctrl-C or a launcher's SIGTERM lands there."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

# Where the signal lands in the module's import. "weakref" is a callback that Python cannot
# propagate an exception from (importlib's module-lock clean-up is one; a CI run printed
# "Exception ignored in: <function _get_module_lock.<locals>.cb>" with our exception).
PLACES = {
    "body": "signal.raise_signal(SIG)\n",
    "weakref": textwrap.dedent("""\
        import weakref
        class _Thing:
            pass
        _t = _Thing()
        _r = weakref.ref(_t, lambda _ref: signal.raise_signal(SIG))
        del _t
        """),
    "del": textwrap.dedent("""\
        class _Thing:
            def __del__(self):
                signal.raise_signal(SIG)
        _Thing()
        """),
}


def _run(tmp_path, module_text: str) -> subprocess.CompletedProcess:
    """Run ``lazy_main`` on a module ``slow_node`` holding ``module_text``."""
    (tmp_path / "slow_node.py").write_text(module_text)
    code = ("import sys; sys.path.insert(0, %r)\n"
            "from hyperarm_description.launcher import lazy_main\n"
            "sys.exit(lazy_main('slow_node')())\n" % str(tmp_path))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("place", sorted(PLACES))
def test_a_signal_during_the_import_is_a_quiet_exit_0(tmp_path, place, sig):
    done = _run(tmp_path, f"import signal\nSIG = signal.{sig}\n{PLACES[place]}\n"
                          "def main():\n    print('main ran')\n")
    assert done.returncode == 0, done.stderr
    assert "main ran" not in done.stdout          # the node never started
    assert "stopped during start-up" in done.stderr
    for bad in ("Traceback", "Exception ignored", "KeyboardInterrupt"):
        assert bad not in done.stderr, done.stderr


def test_other_unraisable_exceptions_are_still_reported(tmp_path):
    """The quiet hook drops only the signal's own exception: a library's failing __del__
    during the import is printed as Python always does, and the node still runs."""
    done = _run(tmp_path, textwrap.dedent("""\
        class _Thing:
            def __del__(self):
                raise ValueError("a library's own defect")
        _Thing()
        def main():
            print("main ran")
        """))
    assert done.returncode == 0, done.stderr
    assert "main ran" in done.stdout
    assert "Exception ignored" in done.stderr and "a library's own defect" in done.stderr



@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_signals_in_a_burst_during_the_import_are_a_quiet_exit_0(tmp_path, sig):
    """A double Ctrl-C, or a launcher's SIGTERM then SIGINT: signals keep coming (every
    2 ms here) while the process exits after the first. Before, Python's finalization put
    SIG_DFL back and a later signal killed the exiting process (-2; seen on ik_service,
    whose import takes up to 7 s on a loaded machine)."""
    import signal as _signal
    import time

    (tmp_path / "slow_node.py").write_text(textwrap.dedent("""\
        import sys, time
        print("importing", flush=True)
        time.sleep(30)
        def main():
            print("main ran")
        """))
    code = ("import sys; sys.path.insert(0, %r)\n"
            "from hyperarm_description.launcher import lazy_main\n"
            "sys.exit(lazy_main('slow_node')())\n" % str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "importing"
        end = time.monotonic() + 10.0
        while proc.poll() is None and time.monotonic() < end:
            proc.send_signal(getattr(_signal, sig))
            time.sleep(0.002)
        out, err = proc.communicate(timeout=10.0)
    finally:
        proc.kill()
    assert proc.returncode == 0, (proc.returncode, err)
    assert "main ran" not in out and "stopped during start-up" in err
    for bad in ("Traceback", "Exception ignored", "KeyboardInterrupt"):
        assert bad not in err, err
