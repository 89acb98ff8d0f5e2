"""Shared pytest fixtures for every hyperarm package (all test tiers).

- ``ros_domain``: a ROS_DOMAIN_ID of the test's own, also exported to os.environ, so
  in-process nodes and the processes a test starts see only each other.
- ``rclpy_context``: an initialised rclpy Context on that domain, shut down afterwards.
- ``executor``: a SingleThreadedExecutor on that context, spun in a thread;
  ``executor.add_node(node)`` and use the node from the test.
- ``launch``: starts installed executables (the same ones `ros2 run` starts) as separate
  processes on that domain, and stops them with SIGINT (then SIGKILL) at teardown, failing
  the test if one does not shut down cleanly.
- ``executable(package, name)``: path of an installed executable (what `ros2 run` runs).
- ``wait_for``: poll a condition with a deadline; returns its last truthy value.
"""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any, Callable

import pytest

# MuJoCo's offscreen rendering (the rendered camera's tests) needs an OpenGL backend where
# there is no display: EGL (scripts/setup.sh installs it). Read when mujoco is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")


def _domain_range() -> tuple[int, int]:
    """Domains this pytest run may use: ``HYPERARM_TEST_DOMAINS=lo-hi`` (inclusive), so that
    test runs going on at the same time on one machine can be given disjoint ranges;
    100-231 by default (all valid ROS 2 domain IDs on Linux are 0-232)."""
    text = os.environ.get("HYPERARM_TEST_DOMAINS", "100-231")
    try:
        lo, hi = (int(part) for part in text.split("-"))
    except ValueError:
        raise RuntimeError(f"HYPERARM_TEST_DOMAINS={text!r}: expected 'lo-hi', e.g. 100-150")
    if not 0 <= lo <= hi <= 232:
        raise RuntimeError(f"HYPERARM_TEST_DOMAINS={text!r}: need 0 <= lo <= hi <= 232")
    return lo, hi


def _worker_range(lo: int, hi: int) -> tuple[int, int]:
    """Under pytest-xdist (``make test`` runs two workers), worker k of n takes the k-th of
    n disjoint slices of the range, so two workers never share a domain."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    if not worker.startswith("gw") or count <= 1:
        return lo, hi
    k, size = int(worker[2:]), (hi - lo + 1) // count
    if size < 1:
        raise RuntimeError(f"HYPERARM_TEST_DOMAINS={lo}-{hi}: too few domains for {count} workers")
    return lo + k * size, lo + (k + 1) * size - 1


_DOMAIN_LO, _DOMAIN_HI = _worker_range(*_domain_range())
_DOMAIN_START = os.getpid()  # a different starting point per pytest run
_domain_counter = [0]


def _next_domain() -> int:
    _domain_counter[0] += 1
    span = _DOMAIN_HI - _DOMAIN_LO + 1
    return _DOMAIN_LO + (_DOMAIN_START + _domain_counter[0]) % span


_TERMINAL_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


def _terminal_signal_state() -> None:
    """Every process a test starts gets the signal state of a person's terminal. A runner
    (CI) may start pytest with SIGTERM ignored or blocked; children inherit that through
    exec, and then `kill $pid` in a shell block or a driver's SIGTERM does nothing (it did
    in CI: a pasted block's background job outlived its `kill`). Code run in-process by a
    test (run_node after a signal, the soak's spawning) may leave them ignored too."""
    if threading.current_thread() is not threading.main_thread():
        return
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _TERMINAL_SIGNALS)
    for sig in _TERMINAL_SIGNALS[1:]:      # SIGINT keeps pytest's own handler
        if signal.getsignal(sig) == signal.SIG_IGN:
            signal.signal(sig, signal.SIG_DFL)
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


#: names this test session (the xdist workers inherit it from the controller): processes
#: on a ROS domain that another session (another checkout's `make test`) also uses are
#: not ours to judge or kill
SESSION_VAR = "HYPERARM_TEST_SESSION"


def pytest_configure(config: pytest.Config) -> None:
    _terminal_signal_state()
    if not hasattr(config, "workerinput"):   # the session itself (an xdist worker inherits it)
        os.environ[SESSION_VAR] = f"{os.getpid()}-{time.time_ns()}"   # (a nested run: its own)


@pytest.fixture(autouse=True)
def _terminal_signals() -> None:
    """Before each test: :func:`_terminal_signal_state` (an earlier test of the same worker
    may have left SIGTERM ignored; the CI run's doc-block test then hung on `kill`)."""
    _terminal_signal_state()


@pytest.fixture(autouse=True)
def _alone(request: pytest.FixtureRequest):
    """Under pytest-xdist, a test marked ``alone`` runs while no other test of the session
    runs: a stop of 16 node processes at once within 2 s measures our shutdown, not how busy
    the other worker keeps the machine (on a 2-core machine, rclpy's destroy then took
    2-2.7 s beside three busy loops, 0.05 s alone; a fresh-clone run still saw 2.3-3.0 s
    once alone, docs/benchmarks.md). The others wait at a gate while it runs;
    it waits for the test the other worker is in to end (give it a pytest timeout that
    covers that wait: the longest test's). Two flock()ed files in a directory of the
    session: ``gate`` (exclusive, briefly; held by an ``alone`` test throughout, so that it
    is not starved) and ``room`` (shared by the others, exclusive for it)."""
    if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1) <= 1:
        yield
        return
    import fcntl
    import tempfile

    folder = Path(tempfile.gettempdir()) / f"hyperarm-test-{os.environ.get(SESSION_VAR, '')}"
    folder.mkdir(exist_ok=True)
    alone = request.node.get_closest_marker("alone") is not None
    with open(folder / "gate", "a") as gate, open(folder / "room", "a") as room:
        fcntl.flock(gate, fcntl.LOCK_EX)
        fcntl.flock(room, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(room, fcntl.LOCK_UN)
            if alone:
                fcntl.flock(gate, fcntl.LOCK_UN)


def processes_on_domain(domain: int) -> list[tuple[int, str]]:
    """(pid, command line) of every live process of this test session started with
    ROS_DOMAIN_ID=``domain`` (this process excepted): what a test started on its own
    domain."""
    found = []
    needle = f"\0ROS_DOMAIN_ID={domain}\0".encode()
    ours = f"\0{SESSION_VAR}={os.environ.get(SESSION_VAR, '')}\0".encode()
    for env_file in Path("/proc").glob("[0-9]*/environ"):
        pid = int(env_file.parent.name)
        if pid == os.getpid():
            continue
        try:
            env = b"\0" + env_file.read_bytes()
            if needle not in env or ours not in env:
                continue
            cmd = (env_file.parent / "cmdline").read_bytes().replace(b"\0", b" ").strip()
            state = (env_file.parent / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue                       # gone meanwhile, or not ours to read
        if cmd and state != "Z":
            found.append((pid, cmd.decode(errors="replace")))
    return found


def _kill(processes: list[tuple[int, str]]) -> None:
    for pid, _ in processes:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


#: The DDS set-up of every test's processes: Fast DDS over UDP loopback only, no shared
#: memory (the profile's header says why: its transport stalls a node's stop for 1-3 s when
#: many participants stop at once, and the processes a test kills leave zombie ports in
#: /dev/shm). SYSTEM_DEFAULT: rmw_fastrtps keeps the profile's transports as they are
#: (LOCALHOST would add its own shared-memory and UDP transports to them); the profile's
#: single interface, 127.0.0.1, keeps discovery on this machine as LOCALHOST did.
_PROFILE = (Path(__file__).resolve().parent / "hyperarm_bringup" / "config"
            / "fastdds_localhost.xml")
if not _PROFILE.is_file():   # a copy of this file elsewhere (test_suite_scheduling's nested
    # run): the profile the outer run exported
    _PROFILE = Path(os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE", _PROFILE))
TEST_DDS_ENV = {
    "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
    "FASTRTPS_DEFAULT_PROFILES_FILE": str(_PROFILE),
}
# without it Fast DDS would fall back to its defaults (multicast on every interface, shared
# memory), so its absence stops the run
assert Path(TEST_DDS_ENV["FASTRTPS_DEFAULT_PROFILES_FILE"]).is_file(), TEST_DDS_ENV
# for this process too (scripts/test.sh sets the same): Fast DDS reads its profile once per
# process, at the first participant, so a fixture's setenv would come too late for pytest's own
os.environ.update(TEST_DDS_ENV)


@pytest.fixture
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> int:
    """A ROS domain of the test's own. Afterwards, nothing the test started may still run
    on it (3 s of grace): a process that outlives its test is killed and fails the test.
    Orphans of one test (run_task.sh's nodes once) otherwise run on into later tests that
    reuse the domain."""
    dom = _next_domain()
    # a process already on the domain is not this test's (an earlier test's orphan that its
    # own check missed): killed, and named in a warning, not blamed on this test
    stray = processes_on_domain(dom)
    _kill(stray)
    if stray:
        import warnings
        warnings.warn(f"ROS domain {dom}: killed before the test, left by an earlier one:\n"
                      + "\n".join(f"  {pid} {cmd[:200]}" for pid, cmd in stray))
    monkeypatch.setenv("ROS_DOMAIN_ID", str(dom))
    for key, value in TEST_DDS_ENV.items():
        monkeypatch.setenv(key, value)
    yield dom
    deadline = time.monotonic() + 3.0
    while (left := processes_on_domain(dom)) and time.monotonic() < deadline:
        time.sleep(0.1)
    _kill(left)
    if left:
        pytest.fail("left running after the test (now killed):\n"
                    + "\n".join(f"  {pid} {cmd[:200]}" for pid, cmd in left))


@pytest.fixture
def rclpy_context(ros_domain: int):
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(rclpy_context):
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=rclpy_context)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set() and rclpy_context.ok():
            ex.spin_once(timeout_sec=0.02)

    thread = threading.Thread(target=spin, name="test-executor", daemon=True)
    thread.start()
    yield ex
    stop.set()
    thread.join(timeout=5.0)
    for node in list(ex.get_nodes()):
        ex.remove_node(node)
        node.destroy_node()
    ex.shutdown(timeout_sec=1.0)


def wait_until(cond: Callable[[], Any], timeout: float, period: float = 0.01,
               what: str | Callable[[], str] = "condition") -> Any:
    """Poll ``cond`` until it returns a truthy value; raise AssertionError at ``timeout``.
    ``what`` names the wait in that error; a callable is called then, so that e.g. a
    process' log in it is the log at the timeout, not the log when the wait began."""
    deadline = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        if time.monotonic() > deadline:
            said = what
            if callable(what):
                try:
                    said = what()
                except Exception as exc:   # the timeout is the failure, not its description
                    said = f"<the wait's description failed: {exc!r}>"
            raise AssertionError(f"timed out after {timeout:.1f} s waiting for {said}")
        time.sleep(period)


@pytest.fixture
def wait_for():
    return wait_until


def executable_path(package: str, name: str) -> str:
    """Path of an installed executable, as `ros2 run package name` would find it."""
    from ament_index_python.packages import get_package_prefix

    path = Path(get_package_prefix(package)) / "lib" / package / name
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: is the workspace built (make setup)?")
    return str(path)


class Launched:
    """A started executable; ``output()`` returns what it printed so far."""

    def __init__(self, proc: subprocess.Popen, log: Path) -> None:
        self.proc = proc
        self.log = log

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""


def _node_env(ros_domain: int, env: dict | None = None) -> dict:
    """The environment of a node the ``launch`` fixture starts on ``ros_domain``."""
    return dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1",
                **TEST_DDS_ENV, **(env or {}))


@pytest.fixture
def launch_env(ros_domain: int) -> Callable[..., dict]:
    """``launch_env(env=None)``: the environment ``launch`` gives a node (for a process a
    test starts itself)."""
    return lambda env=None: _node_env(ros_domain, env)


@pytest.fixture
def launch(ros_domain: int, tmp_path: Path):
    started: list[Launched] = []

    def _launch(package: str, name: str, *args: str, params: dict | None = None,
                namespace: str | None = None, env: dict | None = None) -> Launched:
        cmd = [executable_path(package, name), *args]
        ros_args: list[str] = []
        for key, value in (params or {}).items():
            if isinstance(value, bool):
                value = "true" if value else "false"
            ros_args += ["-p", f"{key}:={value}"]
        if namespace:
            ros_args += ["-r", f"__ns:={namespace}"]
        if ros_args:
            cmd += ["--ros-args", *ros_args]
        log = tmp_path / f"{name}-{len(started)}.log"
        full_env = _node_env(ros_domain, env)
        with open(log, "wb") as fh:
            # cwd: the test's own directory (a node's relative output, e.g. the recorder's
            # task.mcap, must not land in the repository)
            proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=full_env,
                                    start_new_session=True, cwd=tmp_path)
        item = Launched(proc, log)
        started.append(item)
        return item

    yield _launch
    unclean = []
    for item in started:
        if item.proc.poll() is None:
            item.proc.send_signal(signal.SIGINT)
            try:
                item.proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                os.killpg(item.proc.pid, signal.SIGKILL)
                item.proc.wait(timeout=5.0)
                unclean.append(f"{item.log.name}: did not exit on SIGINT\n{item.output()[-2000:]}")
                continue
            if item.proc.returncode not in (0, -signal.SIGINT):
                unclean.append(f"{item.log.name}: exit code {item.proc.returncode} on SIGINT\n"
                               f"{item.output()[-2000:]}")
    if unclean:
        pytest.fail("unclean shutdown:\n" + "\n".join(unclean))


@pytest.fixture
def executable():
    """``executable(package, name)``: path of an installed executable (see executable_path)."""
    return executable_path
