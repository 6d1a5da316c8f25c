"""The exceptions gpm raises.

Every error of the Rust library arrives as a subclass of :class:`GpmError`, with gpm's own
message and, where gpm knows them, the offending ``particle`` (an index into the arrays you
passed) and ``parameter`` (the key, e.g. ``"dt"``, ``"x"``, ``"solve.rel_tol"``).
"""

from __future__ import annotations

from typing import List, Optional


class GpmError(Exception):
    """Base class of every gpm error.

    Attributes:
        particle: index of the offending particle, or ``None``.
        parameter: name of the offending parameter or array, or ``None``.
    """

    particle: Optional[int] = None
    parameter: Optional[str] = None


class InputError(GpmError, ValueError):
    """Bad particle data or parameters: wrong array shape, NaN/Inf values, non-positive
    volumes or time step, a neighbour list out of date, ``h`` below the particle spacing."""


class ConnectivityError(GpmError):
    """The particles violate h-connectivity (reported before any solve).

    Attributes:
        offending: every particle of the unexpected components.
    """

    offending: List[int] = []


class SolveError(GpmError, ArithmeticError):
    """The Poisson (or viscous) solve failed: no convergence, not positive definite, NaN."""


class StabilityError(GpmError):
    """A run became unstable (a scene's stability guard)."""


class RecordError(GpmError, OSError):
    """Recording or replaying failed (the message names the file)."""


class PairWeightError(GpmError, ArithmeticError):
    """The moment-consistent pair weights could not be computed."""


__all__ = [
    "GpmError",
    "InputError",
    "ConnectivityError",
    "SolveError",
    "StabilityError",
    "RecordError",
    "PairWeightError",
]
