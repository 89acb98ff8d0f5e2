"""The IK service's logic without ROS: validate a request, pick the seed, run the solver.

The node converts SolveIK messages to :class:`IKRequest` and :class:`IKResult` back; all the
decisions live here. Units: m, rad, s. Frames: the target must be in the model's root frame
(``base_link``, or ``world`` for the rail variant).
"""
from __future__ import annotations

import math
import queue
import threading
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description import contract
from hyperarm_description.joints import JointStateCache
from hyperarm_description.world import WorldSpec

from .collision import CollisionError, CollisionModel
from .errors import FrameError, InvalidOptionError, InvalidSeedError, InvalidTargetError
from .kinematics import Kinematics
from .solvers import (DEFAULT_ORIENTATION_TOLERANCE, DEFAULT_POSITION_TOLERANCE,
                      DEFAULT_SOLVER, DEFAULT_TIMEOUT, IKResult, Solver, make_solver,
                      solver_names)
from .solvers.base import COLLISION_MODES

__all__ = ["IKRequest", "IKDefaults", "IKCore", "IKPool", "QUATERNION_NORM_TOLERANCE"]

QUATERNION_NORM_TOLERANCE = 1e-3  # |norm - 1| accepted (and then normalised)


@dataclass
class IKRequest:
    """One IK request in plain values. Zero tolerances/timeout mean "the default"."""

    frame_id: str
    position: Sequence[float]                  # m
    orientation: Sequence[float]               # quaternion x, y, z, w
    seed_names: Sequence[str] = ()
    seed_positions: Sequence[float] = ()
    solver: str = ""
    position_only: bool = False
    position_tolerance: float = 0.0            # m
    orientation_tolerance: float = 0.0         # rad
    timeout: float = 0.0                       # s
    collisions: str = ""                       # "" = default, "ignore", "check", "avoid"
    block_held: bool = False                   # the block is in the gripper


@dataclass
class IKDefaults:
    """Defaults applied when a request leaves a field at 0 / empty."""

    solver: str = DEFAULT_SOLVER
    position_tolerance: float = DEFAULT_POSITION_TOLERANCE
    orientation_tolerance: float = DEFAULT_ORIENTATION_TOLERANCE
    timeout: float = DEFAULT_TIMEOUT
    max_timeout: float = 10.0                  # s, longer requests are refused
    collisions: str = "avoid"                  # when a request leaves it empty

    def __post_init__(self) -> None:
        if self.collisions not in COLLISION_MODES:
            raise InvalidOptionError(f"default collisions must be one of "
                                     f"{', '.join(COLLISION_MODES)}, got {self.collisions!r}")
        for name in ("position_tolerance", "orientation_tolerance", "timeout", "max_timeout"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0.0:
                raise InvalidOptionError(f"default {name} must be a finite number > 0, got {v!r}")
        if self.timeout > self.max_timeout:
            raise InvalidOptionError(f"default timeout {self.timeout} s exceeds max_timeout "
                                     f"{self.max_timeout} s")


@dataclass
class IKCore:
    """Builds every applicable solver once (they keep warm state such as their RNG)."""

    kin: Kinematics
    defaults: IKDefaults = field(default_factory=IKDefaults)
    joint_states: JointStateCache = field(default_factory=JointStateCache)
    world: WorldSpec | None = None             # the work cell (None: self-collision only)
    collision_margin: float = 0.0              # m, added to every collision capsule

    def __post_init__(self) -> None:
        self.solvers: dict[str, Solver] = {n: make_solver(n, self.kin)
                                           for n in solver_names(self.kin.variant)}
        try:
            self.collision = CollisionModel(self.kin, self.world, margin=self.collision_margin)
        except CollisionError:
            if self.world is not None:
                raise  # a work cell to avoid, but no robot geometry: refuse to start
            self.collision = None  # a description without capsules: requests that check
            # collisions are refused (with the reason), collisions=ignore ones are served
        for s in self.solvers.values():
            s.use_collision_model(self.collision)
        if self.defaults.solver not in self.solvers:
            make_solver(self.defaults.solver, self.kin)  # raises the precise error
        self.frame = (contract.WORLD_FRAME if self.kin.variant == "rail_arm"
                      else contract.BASE_FRAME)
        if self.frame != self.kin.root_frame:  # a guard on the description, not user input
            raise RuntimeError(f"root frame {self.kin.root_frame} != contract frame {self.frame}")

    # --- request pieces --------------------------------------------------------------
    def solver_for(self, name: str) -> Solver:
        key = name or self.defaults.solver
        solver = self.solvers.get(key)
        if solver is None:
            make_solver(key, self.kin)  # raises UnknownSolverError / UnsupportedVariantError
        return solver

    def target(self, req: IKRequest) -> tuple[np.ndarray, np.ndarray]:
        """(position (3,), rotation (3,3)) of the request, checked."""
        if req.frame_id != self.frame:
            shown = repr(req.frame_id) if req.frame_id else "empty"
            raise FrameError(f"target frame is {shown}; the {self.kin.variant} variant "
                             f"takes targets in {self.frame!r}")
        p = np.asarray(req.position, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InvalidTargetError(f"target position is not 3 finite numbers: {p.tolist()}")
        quat = np.asarray(req.orientation, dtype=float)
        if quat.shape != (4,) or not np.all(np.isfinite(quat)):
            raise InvalidTargetError(f"target orientation is not 4 finite numbers: "
                                     f"{quat.tolist()}")
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            if req.position_only and norm == 0.0:
                return p, np.eye(3)  # orientation ignored; an all-zero quaternion is accepted
            raise InvalidTargetError(f"target quaternion norm is {norm:.6g}, not 1 "
                                     f"(+-{QUATERNION_NORM_TOLERANCE})")
        x, y, z, w = quat / norm
        return p, pin.Quaternion(w, x, y, z).toRotationMatrix()

    def seed(self, req: IKRequest) -> tuple[np.ndarray, str]:
        """Seed from the request, else the latest joint_states, else q = 0; and its source."""
        names = list(req.seed_names)
        values = list(req.seed_positions)
        kin = self.kin
        if names or values:
            if len(values) != len(names):
                raise InvalidSeedError(f"seed has {len(values)} positions for "
                                       f"{len(names)} names")
            if len(set(names)) != len(names):
                dup = sorted({n for n in names if names.count(n) > 1})
                raise InvalidSeedError(f"seed names repeated: {', '.join(dup)}")
            known = set(kin.desc.all_joint_names)
            unknown = [n for n in names if n not in known]
            if unknown:
                raise InvalidSeedError(f"seed has unknown joints {', '.join(unknown)}; "
                                       f"known: {', '.join(kin.desc.all_joint_names)}")
            by_name = dict(zip(names, values))
            missing = [n for n in kin.joint_names if n not in by_name]
            if missing:
                raise InvalidSeedError(f"seed lacks {', '.join(missing)} (give all of "
                                       f"{', '.join(kin.joint_names)} or none)")
            q = np.array([float(by_name[n]) for n in kin.joint_names])
            bad = [n for n, v in zip(kin.joint_names, q) if not math.isfinite(v)]
            if bad:
                raise InvalidSeedError(f"seed is not finite for {', '.join(bad)}")
            return q, "request"
        if self.joint_states.has(kin.joint_names):
            q = self.joint_states.positions(kin.joint_names)
            if np.all(np.isfinite(q)):
                return q, "joint_states"
        return np.zeros(kin.nq), "ready pose q = 0"

    def options(self, req: IKRequest) -> tuple[float, float, float]:
        """(position tolerance m, orientation tolerance rad, timeout s) with defaults."""
        out = []
        for name, v, default in (
                ("position_tolerance", req.position_tolerance, self.defaults.position_tolerance),
                ("orientation_tolerance", req.orientation_tolerance,
                 self.defaults.orientation_tolerance),
                ("timeout", req.timeout, self.defaults.timeout)):
            v = float(v)
            if not math.isfinite(v) or v < 0.0:
                raise InvalidOptionError(f"{name} must be >= 0 (0 = default), got {v!r}")
            out.append(v if v > 0.0 else default)
        if out[2] > self.defaults.max_timeout:
            raise InvalidOptionError(f"timeout {out[2]} s exceeds the node's max_timeout "
                                     f"{self.defaults.max_timeout} s")
        return out[0], out[1], out[2]

    # --- the whole request -------------------------------------------------------------
    def solve(self, req: IKRequest) -> tuple[IKResult, str]:
        """Solve ``req``; returns the result and the seed's source. Raises IKError."""
        solver = self.solver_for(req.solver)
        p, r = self.target(req)
        ptol, otol, timeout = self.options(req)
        mode = req.collisions or self.defaults.collisions
        if mode not in COLLISION_MODES:
            raise InvalidOptionError(f"collisions must be one of {', '.join(COLLISION_MODES)} "
                                     f"(or empty: the default), got {mode!r}")
        q0, source = self.seed(req)
        result = solver.solve(p, r, q0, position_only=bool(req.position_only),
                              position_tolerance=ptol, orientation_tolerance=otol,
                              timeout=timeout, collisions=mode, held=bool(req.block_held))
        return result, source


class IKPool:
    """``size`` independent :class:`IKCore` s for concurrent requests (one per thread).

    Pinocchio's data and the solvers' scratch state are not shared between threads, so
    every core has its own Kinematics and solvers (the default solver's start table is
    shared read-only). :meth:`solve` borrows a free core for the request, waiting if all
    ``size`` are busy; the joint_states cache is common to all. Thread-safe.
    """

    def __init__(self, kin_factory, defaults: IKDefaults | None = None, size: int = 4,
                 world: WorldSpec | None = None, collision_margin: float = 0.0) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise InvalidOptionError(f"pool size must be an integer >= 1, got {size!r}")
        self.joint_states = JointStateCache()
        defaults = defaults if defaults is not None else IKDefaults()
        self.cores = [IKCore(kin_factory(), defaults, self.joint_states, world,
                             collision_margin) for _ in range(size)]
        self._free: queue.SimpleQueue[IKCore] = queue.SimpleQueue()
        for core in self.cores:
            self._free.put(core)
        self._lock = threading.Lock()
        self.busy = 0          # cores solving right now
        self.peak_busy = 0     # most cores ever busy at once

    @property
    def size(self) -> int:
        return len(self.cores)

    @property
    def kin(self) -> Kinematics:
        return self.cores[0].kin

    @property
    def frame(self) -> str:
        return self.cores[0].frame

    @property
    def defaults(self) -> IKDefaults:
        return self.cores[0].defaults

    def update_joint_states(self, names, position, velocity=(), effort=()) -> None:
        with self._lock:
            self.joint_states.update(names, position, velocity, effort)

    def solve(self, req: IKRequest) -> tuple[IKResult, str]:
        """Like :meth:`IKCore.solve`, on a free core (waits for one if all are busy)."""
        core = self._free.get()
        with self._lock:
            self.busy += 1
            self.peak_busy = max(self.peak_busy, self.busy)
        try:
            return core.solve(req)
        finally:
            with self._lock:
                self.busy -= 1
            self._free.put(core)
