"""Run ``dxl_emulator`` as a separate process (tests, benchmark, scripts). No ROS."""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .emulator import EmulatorControl

__all__ = ["EmulatorProcess"]


class EmulatorProcess:
    """``with EmulatorProcess(*args) as emu:`` starts the emulator on a pty with a stable
    link ``emu.link`` and a control client ``emu.ctl``; stops it on exit."""

    def __init__(self, *args: str, workdir: str | os.PathLike[str] | None = None,
                 timeout: float = 20.0) -> None:
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix="dxlemu-")
        base = Path(workdir) if workdir else Path(self._tmp.name)  # type: ignore[union-attr]
        self.link = str(base / "ttyDXL")
        self.control_path = str(base / "dxl.ctl")
        self.log = base / "emulator.log"
        cmd = [sys.executable, "-m", "hyperarm_driver.dynamixel.emulator", "--link", self.link,
               "--control", self.control_path, *args]
        self._fh = open(self.log, "wb")
        self.proc = subprocess.Popen(cmd, stdout=self._fh, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout
        while not (os.path.exists(self.control_path) and os.path.exists(self.link)):
            if self.proc.poll() is not None:
                raise RuntimeError(f"dxl_emulator exited: {self.log.read_text()}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError("dxl_emulator did not start")
            time.sleep(0.02)
        while True:    # the socket file exists from bind(), connections from listen() on
            try:
                self.ctl = EmulatorControl(self.control_path)
                break
            except ConnectionRefusedError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError("dxl_emulator control socket refuses connections")
                time.sleep(0.02)

    def stop(self) -> None:
        if getattr(self, "ctl", None) is not None:
            self.ctl.close()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._fh.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
