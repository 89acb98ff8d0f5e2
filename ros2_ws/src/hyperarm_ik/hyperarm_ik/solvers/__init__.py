"""IK solvers by name: the paper's (pinv, weighted_pinv, heuristic, wln, augmented) and ours.

``make_solver(name, kin, **options)`` builds one; ``""`` means the default solver.
"""
from __future__ import annotations

from ..errors import UnknownSolverError
from ..kinematics import Kinematics
from .augmented import AugmentedSolver
from .base import (DEFAULT_ORIENTATION_TOLERANCE, DEFAULT_POSITION_TOLERANCE, DEFAULT_TIMEOUT,
                   IKResult, Solver)
from .default import DefaultSolver
from .heuristic import HeuristicSolver
from .pinv import PinvSolver
from .weighted_pinv import WeightedPinvSolver
from .wln import WlnSolver

__all__ = ["SOLVERS", "DEFAULT_SOLVER", "make_solver", "solver_names", "IKResult", "Solver",
           "DEFAULT_POSITION_TOLERANCE", "DEFAULT_ORIENTATION_TOLERANCE", "DEFAULT_TIMEOUT"]

DEFAULT_SOLVER = DefaultSolver.name
SOLVERS: dict[str, type[Solver]] = {
    cls.name: cls for cls in (DefaultSolver, PinvSolver, WeightedPinvSolver, HeuristicSolver,
                              WlnSolver, AugmentedSolver)
}


def solver_names(variant: str | None = None) -> list[str]:
    """Names of the solvers (those applying to ``variant`` if given)."""
    return [n for n, c in SOLVERS.items() if variant is None or variant in c.variants]


def make_solver(name: str, kin: Kinematics, **options) -> Solver:
    """Solver ``name`` ("" = default) on ``kin``.

    Raises UnknownSolverError naming the valid ones, UnsupportedVariantError for a solver
    that does not apply to ``kin``'s variant, InvalidOptionError for bad ``options``.
    """
    key = name or DEFAULT_SOLVER
    try:
        cls = SOLVERS[key]
    except KeyError:
        raise UnknownSolverError(
            f"unknown solver {name!r}; valid: {', '.join(solver_names(kin.variant))}") from None
    return cls(kin, **options)
