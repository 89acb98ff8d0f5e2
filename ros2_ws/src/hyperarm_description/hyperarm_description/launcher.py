"""Entry points that are quiet about a signal during start-up (no rclpy, no numpy needed).

A node's module imports rclpy, pinocchio and numpy before its ``main()`` can install the
signal handling of :func:`hyperarm_description.ros_main.run_node`; on a loaded robot
computer that takes seconds. A Ctrl-C or SIGTERM in that window would print a
``KeyboardInterrupt`` traceback (or end the process with -15) although nothing has started.
:func:`lazy_main` makes a console-script entry point that installs a handler first, imports
the node module, and exits 0 if a signal came before the node's own main took over.
"""
from __future__ import annotations

import importlib
import os
import signal
import sys
from typing import Any, Callable

__all__ = ["lazy_main"]


class _StoppedDuringStartup(BaseException):
    """A signal arrived while the node module was being imported (not an error)."""


_signalled: list[int] = []


def _on_signal(signum: int, _frame: Any) -> None:
    # every later signal is ignored from here on (a second one must not raise again inside
    # the exit path, nor meet Python's SIG_DFL during finalization: exit -2)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    _signalled.append(signum)   # kept even if a library's import swallows the exception
    raise _StoppedDuringStartup


def _quiet_unraisable(unraisable: Any) -> None:
    """``sys.unraisablehook`` for start-up: the signal's exception raised where Python cannot
    propagate it (a weakref callback such as importlib's module-lock clean-up, a
    ``__del__``) is dropped, since ``_signalled`` already holds it; anything else goes to
    Python's own hook."""
    if isinstance(unraisable.exc_value, _StoppedDuringStartup):
        return
    sys.__unraisablehook__(unraisable)


def lazy_main(module: str, attr: str = "main") -> Callable[[], Any]:
    """A ``console_scripts`` target that runs ``module.attr()`` (``module`` imported only
    when the entry point runs), exiting 0 on SIGINT/SIGTERM during the import."""

    def entry() -> Any:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _on_signal)
        sys.unraisablehook = _quiet_unraisable
        try:
            main = getattr(importlib.import_module(module), attr)
            if _signalled:      # the exception was swallowed inside some import
                raise _StoppedDuringStartup
            # run_node() replaces the handler at once; a signal in between is still quiet.
            return main()
        except _StoppedDuringStartup:
            # (later signals are ignored since the first: _on_signal)
            try:
                print("stopped during start-up", file=sys.stderr, flush=True)
                sys.stdout.flush()
            except (OSError, ValueError):   # a closed or broken pipe: nothing to tell
                pass
            # nothing of ours has started: skip the interpreter's finalization of what was
            # imported (pinocchio, the DDS library: up to 1.9 s on a loaded machine)
            os._exit(0)

    entry.__name__ = entry.__qualname__ = f"{module.rsplit('.', 1)[-1]}_{attr}"
    entry.__doc__ = f"Entry point of {module}.{attr} (see hyperarm_description.launcher)."
    return entry


def installed_executable(package: str, name: str) -> str:
    """Path of an installed executable of ``package``, as ``ros2 run package name`` finds
    it; raises FileNotFoundError saying to build the workspace."""
    from pathlib import Path

    from ament_index_python.packages import get_package_prefix

    path = Path(get_package_prefix(package)) / "lib" / package / name
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: is the workspace built (make setup)?")
    return str(path)
