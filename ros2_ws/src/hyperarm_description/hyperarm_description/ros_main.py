"""The one `main()` of every hyperarm node (imports rclpy: for nodes only).

The ros2/demos pattern, written once, with what a node on a robot needs around it:

- ``--help`` / ``-h`` prints the node's usage and its parameters (from the same table the
  node declares them from) and exits 0 without starting anything.
- Signals: the first SIGINT or SIGTERM asks the node to stop; the spin loop ends, the node is
  destroyed (its shutdown policy runs: torque policy, rail stop...) and rclpy shuts down.
  Further SIGINT/SIGTERM during that clean-up are ignored (one line on stderr), so a second
  quick Ctrl-C cannot skip the shutdown policy or crash the process. Exit code 0, at once
  after the clean-up when run from the command line (``args`` None): the interpreter's
  finalization is skipped (:func:`_exit_now`). A clean-up over 1 s prints its phases.
  rclpy's own signal handlers are not installed: they shut the context down under the
  node's feet, so clean-up code could not publish, log to /rosout or call services.
- A node constructor that raises SystemExit (bad parameters, bad description) ends the
  process with that message and exit code 1, after the same clean-up. A signal while the
  constructor runs (e.g. a driver waiting for its port) aborts it the same way, exit 0.
- An exception raised by a callback while the node is up is raised (a bug is not hidden).
"""
from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING, Any, Callable

import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from .model import VARIANTS
from .params import ParamSpec, declare_parameters, format_parameters

if TYPE_CHECKING:
    from .model import RobotDescription

__all__ = ["run_node", "declare_robot_description", "ROBOT_PARAMETERS", "usage_text",
           "wants_help", "EXECUTORS", "make_executor"]

#: The parameters every node that loads the robot description declares (see
#: :func:`declare_robot_description`).
ROBOT_PARAMETERS: ParamSpec = {
    "variant": ("arm", f"robot variant: {' or '.join(VARIANTS)}", None),
    "description_file": ("", "robot description YAML ('' = the packaged "
                             "config/hyperarm.yaml)", None),
}

_SPIN_PERIOD = 0.1  # s: how often the spin loop looks at the stop flag
_FLUSH_TIME = 0.2    # s: spins after a node's before_shutdown() (its results go out)

#: s: a clean-up that takes longer prints its phases' durations on stderr
SLOW_SHUTDOWN = 1.0
#: s: a clean-up still running this long after the stopping signal prints every thread's
#: stack on stderr and ends the process with exit code 1 (faulthandler's watchdog, a C
#: thread: it works while a DDS call that never returns holds the main thread, as Fast DDS'
#: teardown did in 2 of about 60 lifecycle runs here). Long enough for the clean-up's own
#: waits (up to 6.2 s before the node's shutdown policy) and a slow bus; short of the 10 s
#: after which ros2 launch and run_task.sh SIGKILL.
STUCK_SHUTDOWN = 8.0

#: Executors :func:`run_node` can build by name: ``single`` (rclpy's
#: SingleThreadedExecutor, the default) and ``events`` (rclpy.experimental.EventsExecutor:
#: the wait and the dispatch in C++, far less Python per callback; no guard conditions).
EXECUTORS = ("single", "events")


def make_executor(name: str, context: "rclpy.context.Context | None" = None) -> Executor:
    """The executor called ``name`` (one of :data:`EXECUTORS`) on ``context``."""
    if name == "single":
        return SingleThreadedExecutor(context=context)
    if name == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    raise ValueError(f"executor {name!r}: one of {', '.join(EXECUTORS)}")


def wants_help(args: list[str] | None = None) -> bool:
    """True if the non-ROS command-line arguments ask for ``--help`` or ``-h``."""
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if args is None else args)
    return any(a in ("-h", "--help") for a in remove_ros_args(argv)[1:])


def usage_text(prog: str, summary: str, parameters: ParamSpec | None,
               robot_description: bool) -> str:
    """The ``--help`` text of a node executable."""
    table: dict[str, Any] = {}
    if robot_description:
        table.update(ROBOT_PARAMETERS)
    table.update(parameters or {})
    lines = [f"usage: ros2 run <package> {prog} [-h] [--ros-args -p NAME:=VALUE ...]", ""]
    lines += [summary.strip(), ""] if summary.strip() else []
    lines.append("parameters (read-only, set with --ros-args -p NAME:=VALUE):")
    lines.append(format_parameters(table) if table else "  (none)")
    lines += ["", "The node runs in the namespace /hyperarm (remap with -r __ns:=/other).",
              "SIGINT or SIGTERM stop it cleanly (exit code 0); bad parameters exit 1."]
    return "\n".join(lines)


def _module_summary(factory: Callable[..., Any]) -> str:
    """The first paragraph of the docstring of the module that defines ``factory``."""
    module = sys.modules.get(getattr(factory, "__module__", ""), None)
    doc = (getattr(module, "__doc__", None) or getattr(factory, "__doc__", None) or "").strip()
    return doc.split("\n\n")[0]


class _Stop:
    """SIGINT/SIGTERM handling: the first signal asks to stop (and, while the node is being
    built, aborts its constructor); later ones are ignored while the clean-up runs."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.building = True
        self.building_aborted = False  # the node's constructor was stopped by a signal
        self.signalled = False
        self._previous: dict[int, Any] = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return  # signal handlers can only be set from the main thread (e.g. in tests)
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handle)

    def ignore(self) -> None:
        """SIG_IGN from now on: Python's finalization resets every handler it installed to
        SIG_DFL (but leaves SIG_IGN), so a late second Ctrl-C would kill the exiting
        process with SIGINT (exit -2) instead of letting it finish with 0."""
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, signal.SIG_IGN)

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum: int, _frame: Any) -> None:
        if self.event.is_set():
            print(f"[{signal.Signals(signum).name}] already shutting down", file=sys.stderr,
                  flush=True)
            return
        self.signalled = True
        self.event.set()
        if self.building:
            raise KeyboardInterrupt


def spinner_alive(spinner: threading.Thread | None) -> bool:
    return spinner is not None and spinner.is_alive()


def run_node(factory: Callable[[], Node], args: list[str] | None = None,
             executor: Callable[[], Executor] | str | None = None, *,
             parameters: ParamSpec | None = None, summary: str | None = None,
             robot_description: bool = True) -> None:
    """Spin the node made by ``factory`` until SIGINT/SIGTERM; ``executor`` builds a custom
    executor, or names one of :data:`EXECUTORS` (opt-in; default: ``single``, rclpy's
    SingleThreadedExecutor); with a name, a node that declares a string parameter
    ``executor`` chooses by its value (validate it in the node). ``parameters`` (the node's table), ``summary`` (default: the
    first paragraph of the node module's docstring) and ``robot_description`` (the node declares
    ``variant`` and ``description_file``) make its ``--help``.

    The executor spins in a thread of its own; the main thread only waits for a signal (a
    thread blocked in rcl's wait set would not run Python's signal handlers), then wakes the
    executor with a guard condition, waits for the callbacks in flight, calls the node's
    ``before_shutdown()`` if it has one (e.g. abort a running action goal so that its client
    gets a result; it returns True when it produced something to send, and only then are
    there 0.2 s more of spins to send it: an idle node stops without them), destroys the
    node (its shutdown policy) and shuts rclpy down."""
    if wants_help(args):
        prog = os.path.basename((sys.argv if args is None else args or ["node"])[0])
        text = summary if summary is not None else _module_summary(factory)
        try:
            print(usage_text(prog, text, parameters, robot_description), flush=True)
        except BrokenPipeError:  # e.g. `--help | head`: not an error of ours
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return
    stop = _Stop()
    stop.install()
    context = rclpy.get_default_context()
    rclpy.init(args=args, context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    ex = None
    failure: list[BaseException] = []
    spinner = None
    wake = None
    try:
        node = factory()
        stop.building = False
        if isinstance(executor, str) and node.has_parameter("executor"):
            executor = str(node.get_parameter("executor").value)  # the node's own choice
        if executor is None or isinstance(executor, str):
            ex = make_executor(executor or "single", context)
        else:
            ex = executor()
        ex.add_node(node)
        if isinstance(ex, Executor):
            wake = node.create_guard_condition(lambda: None, ReentrantCallbackGroup()).trigger
        else:   # the EventsExecutor (not an rclpy Executor): no guard conditions, wake()
            wake = ex.wake

        def spin() -> None:
            try:
                while not stop.event.is_set() and context.ok():
                    ex.spin_once(timeout_sec=_SPIN_PERIOD)
            except ExternalShutdownException:
                pass
            except BaseException as exc:
                # A context shut down from elsewhere while callbacks run makes a publish or
                # a wait set fail with an RCLError: that is the shutdown, not a bug. While
                # the context is up an exception is one: handed to the main thread, raised.
                if context.ok():
                    failure.append(exc)
            finally:
                stop.event.set()

        spinner = threading.Thread(target=spin, name="run_node-spin", daemon=True)
        spinner.start()
        while not stop.event.is_set():
            stop.event.wait(0.5)  # signal handlers run in the main thread, between waits
    except KeyboardInterrupt as exc:
        if not stop.event.is_set():
            raise  # not one of our signals
        # else: a signal while the node was being built; clean exit below, the half-built
        # node destroyed first (rclpy shut down under a live node took 2.1 s once)
        if node is None:
            node = _half_built_node(exc)
    except BaseException as exc:
        # a constructor that failed (a bad parameter's SystemExit): its half-built node is
        # destroyed below too, then the exception goes on
        if node is None and stop.building:
            node = _half_built_node(exc)
        raise
    finally:
        stop.building_aborted = stop.building
        stop.building = False
        stop.event.set()  # from here on, signals are ignored
        # a process of its own (not a node run inside a test's process), stopped by a signal
        watchdog = args is None and stop.signalled and _arm_watchdog()
        phases = _Phases()
        if spinner is not None:
            if wake is not None:
                wake()
            spinner.join(timeout=2.0)
            phases.done("spin thread")
        if (ex is not None and node is not None and not spinner_alive(spinner)
                and context.ok() and callable(getattr(node, "before_shutdown", None))):
            # the node ends what clients wait for (an action goal: aborted, saying so);
            # when it did (True), a few spins here send it out while the context is up
            if node.before_shutdown():
                end = time.monotonic() + _FLUSH_TIME
                while time.monotonic() < end:
                    ex.spin_once(timeout_sec=0.01)
            phases.done("before_shutdown")
        if ex is not None:
            ex.shutdown(timeout_sec=2.0)
            _wait_callbacks_in_flight(ex, timeout=2.0)
            phases.done("executor")
        name = None
        if node is not None:
            name = node.get_name()
            with _RclpyDestroyTimer() as rclpy_destroy:
                if stop.building_aborted:
                    _destroy_half_built(node)
                else:
                    node.destroy_node()
            phases.done("node", rclpy_destroy.spans())
        rclpy.try_shutdown()
        phases.done("rclpy")
        phases.report(name)
        if watchdog and failure:
            faulthandler.cancel_dump_traceback_later()   # (else it guards _exit_now too)
        if stop.signalled:
            stop.ignore()  # the process is on its way out
        else:
            stop.restore()
    if failure:
        raise failure[0]
    if args is None and stop.signalled:
        _exit_now()


def _exit_now() -> None:
    """End a node process stopped by a signal as soon as its clean-up is done: stdout and
    stderr flushed, then ``os._exit(0)``. The interpreter's own finalization (module
    teardown and the DDS library's static destructors, 0.15-0.2 s of CPU per process after
    rclpy has shut down) would only delay a script waiting for the node: it kept
    run_task.sh's Ctrl-C waiting 3.4 s once, on a loaded machine. Nothing of ours runs at
    exit (no atexit handlers): the node's shutdown policy ran in destroy_node."""
    import ctypes
    import logging

    logging.shutdown()                  # Python logging handlers, if any were set up
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # closed or broken pipe: nothing more to say
            pass
    try:
        ctypes.CDLL(None).fflush(None)  # C stdio: rcutils' console output to a pipe/file
    except (OSError, AttributeError):
        pass
    os._exit(0)


def _arm_watchdog() -> bool:
    """Arm faulthandler's watchdog (:data:`STUCK_SHUTDOWN`); False where it cannot be
    (no file descriptor behind stderr): the clean-up then runs without it."""
    try:
        faulthandler.dump_traceback_later(STUCK_SHUTDOWN, exit=True)
    except (RuntimeError, ValueError, OSError, AttributeError):
        return False
    return True


def _half_built_node(exc: BaseException) -> Node | None:
    """The node whose constructor ``exc`` (a signal's KeyboardInterrupt) stopped: the
    outermost ``self`` that is a Node in the traceback, or None (stopped before rclpy's
    Node.__init__ ran)."""
    tb = exc.__traceback__
    while tb is not None:
        candidate = tb.tb_frame.f_locals.get("self")
        if isinstance(candidate, Node):
            try:
                candidate.handle  # noqa: B018 (rclpy's Node.__init__ got as far as rcl)
            except Exception:
                return None
            return candidate
        tb = tb.tb_next
    return None


def _destroy_half_built(node: Node) -> None:
    """Destroy a node whose constructor did not finish: its own ``destroy_node()`` (its
    shutdown policy) where that works on a partial object, else rclpy's, else (stopped
    inside rclpy's own Node.__init__) the rcl node alone."""
    for what, destroy in (("its destroy_node", node.destroy_node),
                          ("rclpy's destroy_node", lambda: Node.destroy_node(node)),
                          ("the rcl node", lambda: node.handle.destroy_when_not_in_use())):
        try:
            destroy()
            return
        except Exception as exc:  # e.g. an attribute its (or rclpy's) constructor never set
            print(f"[{node.get_name()}] half-built node: {what} failed "
                  f"({type(exc).__name__}: {exc})", file=sys.stderr, flush=True)


class _RclpyDestroyTimer:
    """Times rclpy's own ``Node.destroy_node`` (its entities and the rcl node; with the last
    node, the DDS participant) apart from what a node's override does around it (its
    shutdown policy), while the ``with`` block runs: a slow stop's report says which."""

    def __init__(self) -> None:
        self._spans: list[float] = []
        self._original = Node.destroy_node

    def __enter__(self) -> "_RclpyDestroyTimer":
        original, spans = self._original, self._spans

        def timed(node: Node) -> None:
            t0 = time.monotonic()
            try:
                original(node)
            finally:
                spans.append(time.monotonic() - t0)

        Node.destroy_node = timed   # (the process is on its way out; restored below)
        return self

    def __exit__(self, *exc: object) -> None:
        Node.destroy_node = self._original

    def spans(self) -> str:
        return f"rclpy's destroy {sum(self._spans):.2f} s" if self._spans else ""


class _Phases:
    """Durations of the clean-up's phases; :meth:`report` prints them on stderr when the
    whole took longer than :data:`SLOW_SHUTDOWN` (a stop that keeps a script waiting says
    where the time went)."""

    def __init__(self) -> None:
        self._t0 = self._last = time.monotonic()
        self._parts: list[tuple[str, float]] = []

    def done(self, what: str, detail: str = "") -> None:
        now = time.monotonic()
        self._parts.append((what, now - self._last, detail))
        self._last = now

    def report(self, name: str | None) -> None:
        total = self._last - self._t0
        if total > SLOW_SHUTDOWN:
            parts = ", ".join(f"{what} {dt:.2f} s" + (f" ({detail})" if detail else "")
                              for what, dt, detail in self._parts)
            print(f"[{name or 'node'}] shutdown took {total:.2f} s ({parts})", file=sys.stderr,
                  flush=True)


def _wait_callbacks_in_flight(ex: Executor, timeout: float) -> None:
    """Wait for callbacks a MultiThreadedExecutor handed to its thread pool, and collect their
    exceptions, before the node is destroyed. rclpy Jazzy's ``Executor.shutdown`` does not
    wait for them (it tests ``_is_shutdown`` right after setting it), so a callback still
    running would use a destroyed entity and print "exception never retrieved: cannot use
    Destroyable"."""
    pending = list(getattr(ex, "_futures", []))
    deadline = time.monotonic() + timeout
    for task in pending:
        while not task.done() and time.monotonic() < deadline:
            time.sleep(0.005)
        if task.done():
            task.exception()  # fetched: the callback's error was logged by rclpy already
    pool = getattr(ex, "_executor", None)
    if pool is not None:
        pool.shutdown(wait=False, cancel_futures=True)


def declare_robot_description(node: Node) -> "RobotDescription":
    """Declare the common read-only parameters of :data:`ROBOT_PARAMETERS` (``variant``,
    ``description_file``) on ``node`` and load the description they name. Raises SystemExit
    with the reason if a value or the file is bad (the node cannot run without its robot)."""
    from .model import DescriptionError, load_description

    values = declare_parameters(node, ROBOT_PARAMETERS)
    try:
        return load_description(values["description_file"] or None, values["variant"])
    except DescriptionError as exc:
        raise SystemExit(f"{node.get_name()}: {exc}") from exc
