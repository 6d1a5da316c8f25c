"""Type stubs and documentation of the native module ``gpm._gpm`` (re-exported by ``gpm``)."""

from __future__ import annotations

from os import PathLike
from typing import Any, Dict, List, Literal, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

ArrayLike = npt.ArrayLike
FloatArray = npt.NDArray[np.float64]
Config = Union[Dict[str, Any], str, None]

SCENES: List[str]
"""The registered scenes (``"cavity"``, ``"taylor_green"``, ``"channel"``)."""

__version__: str

def lattice(lo: Sequence[float], hi: Sequence[float], dx: float) -> FloatArray:
    """The cell-centred lattice of spacing ``dx`` in the box ``[lo, hi]`` (2 or 3 dimensions):
    points ``lo + (i + 0.5) dx``, the last axis varying fastest. Shape ``(n, dim)``."""

def _rust_own_loop(n: int, steps: int, dt: float, drag: float) -> Tuple[List[float], List[float]]:
    """The loop of ``examples/own_loop.rs`` run entirely in Rust (for ``bench_overhead.py``):
    the wall seconds and the kinetic energy of each step."""

def run_scene(
    name: str,
    config: Config = None,
    *,
    record: Union[str, PathLike[str], None] = None,
    level: Literal["none", "diagnostics", "full"] = "diagnostics",
    every: int = 10,
) -> Dict[str, Any]:
    """Runs a registered scene (``gpm run NAME`` without the files).

    Args:
        name: one of :data:`SCENES`.
        config: the scene's configuration keys (those of ``gpm run NAME --config FILE``), as a
            dict or JSON text; ``None`` for the defaults. Unknown keys raise ``InputError``
            naming the key.
        record: write the run to this MCAP file (its directory is locked for the run).
        level: what to record.
        every: particle snapshots every this many steps (level ``"full"``).

    Returns:
        ``{"scene", "summary", "result", "tables", "steps", "end", "record"}``: the summary
        (``summary.json``), the full result, the tables as CSV text by file name (the cavity:
        ``profile_u.csv``, ``profile_v.csv``), the number of steps, how the run ended and what
        the recorder wrote (or ``None``).

    Ctrl-C stops the run after the current step and raises ``KeyboardInterrupt``.
    """

class Boundary:
    """What surrounds the particles of a :class:`System`."""

    @staticmethod
    def none() -> Boundary:
        """No boundary (free space)."""
    @staticmethod
    def periodic(lo: Sequence[float], hi: Sequence[float]) -> Boundary:
        """Every axis periodic on the box ``[lo, hi)``."""
    @staticmethod
    def closed_box(lo: Sequence[float], hi: Sequence[float]) -> Boundary:
        """Stationary no-slip walls on every face of ``[lo, hi]`` (mirror ghosts)."""
    @staticmethod
    def channel(lo: Sequence[float], hi: Sequence[float]) -> Boundary:
        """Walls at both ends of the last axis, periodic along the others."""
    @staticmethod
    def cavity(side: float = 1.0, lid: float = 1.0, dim: int = 2) -> Boundary:
        """The lid-driven cavity ``[0, side]^dim``; the top wall moves with ``lid`` along x."""
    @property
    def dim(self) -> Optional[int]:
        """The dimension the boundary is made for (``None`` for :meth:`none`)."""

class StepReport:
    """What one projection step did and measured (gpm's ``StepReport``)."""

    @property
    def dt(self) -> float: ...
    @property
    def c0(self) -> float:
        """Semi-regularity constant over the fluid."""
    @property
    def min_spacing(self) -> float:
        """Smallest distance between a fluid particle and any neighbour."""
    @property
    def stability_ratio(self) -> float:
        """Theorem 4.5 ratio ``‖φ‖_h01 / (√(d c0) ‖f‖_ℓ2)``; the theory bounds it by 1."""
    @property
    def div_before(self) -> float:
        """``‖∇̂h·u*‖_ℓ2`` before the projection."""
    @property
    def div_after(self) -> float:
        """``‖∇̂h·uⁿ⁺¹‖_ℓ2`` after it, measured the same way."""
    @property
    def correction_ratio(self) -> float:
        """``‖uⁿ⁺¹ − u*‖ / ‖u*‖``."""
    @property
    def kinetic_energy(self) -> float:
        """``½ ρ Σ ω_i |u_i|²`` after the step."""
    @property
    def max_speed(self) -> float: ...
    @property
    def connectivity(self) -> Dict[str, int]:
        """``components``, ``anchored``, ``floating``, ``isolated``."""
    @property
    def solve(self) -> Dict[str, Any]:
        """The Poisson solve: solver, unknowns, iterations, residuals, reuse, timings."""
    @property
    def viscous(self) -> Optional[Dict[str, Any]]:
        """The implicit viscous solve of :meth:`System.step`'s predictor, with the keys of
        :attr:`solve` (``None`` when none ran: :meth:`System.project`, explicit or no
        viscosity)."""
    @property
    def timings(self) -> Dict[str, float]:
        """Seconds per stage (diagnostics, predictor, source, solve, correction)."""
    def to_dict(self) -> Dict[str, Any]:
        """Every field, nested as in the recorded ``/diagnostics`` messages' ``report``."""

class System:
    """Particles, neighbour list, boundary and projection of your own particle loop.

    The loop stays yours: move the particles, add your forces, and call
    :meth:`update_neighbors`, :meth:`predict` and :meth:`project` (or :meth:`step`).

    Args:
        x: positions, shape ``(n, 2)`` or ``(n, 3)``.
        u: velocities, same shape.
        h: influence radius (typically 2–4 particle spacings).
        skin: neighbour-search skin (candidates within ``h + skin`` are kept while no particle
            moved more than ``skin / 2``); 0 searches at every update.
        weight: ``"wendland2"`` (default), ``"wendland4"``, ``"cubic"``, ``"polyP-M"``.
        boundary: :class:`Boundary` (default: none).
        p: pressures, shape ``(n,)`` (default 0).
        vol: volumes, shape ``(n,)`` (needed with ``volumes="fixed"``).
        dirichlet: per particle, True for the Dirichlet band (prescribed zero pressure
            increment: free surfaces, open boundaries).
        volumes: ``"number_density"`` (``ω_i = 1/Σ_j w_h(r_ij)``, recomputed by every
            :meth:`update_neighbors`) or ``"fixed"``.
        nu: kinematic viscosity (0 skips the viscous stage).
        rho: density.
        scheme: ``"rotational"`` (default), ``"incremental"`` or ``"non_incremental"``.
        viscous_theta: implicit weight of the viscous term (0 explicit, 0.5 Crank–Nicolson).
        gravity: body force per unit mass, ``dim`` components.
        allowed_floating: floating (pure Neumann) components allowed: 1 for a closed or
            periodic box, 0 when a Dirichlet band touches all the fluid.
        solve: the linear solve's keys (``{"solver": "cg", "rel_tol": 1e-10}``, …).

    Raises:
        InputError: a bad array shape, NaN/Inf, a bad parameter (named in ``parameter``),
            ``h`` at or below the particle spacing.

    Arrays: the ``x``, ``u``, ``p``, ``vol`` properties return copies of the caller's
    particles (ghosts excluded): the projection swaps its buffers every step, so views would
    go stale. Assign to them to change gpm's state. :meth:`predict` returns a fresh array
    without copying; ``accel`` and ``u_star`` are read in place when they are C-contiguous
    float64 arrays.
    """

    def __init__(
        self,
        x: ArrayLike,
        u: ArrayLike,
        *,
        h: float,
        skin: float = 0.0,
        weight: str = "wendland2",
        boundary: Optional[Boundary] = None,
        p: Optional[ArrayLike] = None,
        vol: Optional[ArrayLike] = None,
        dirichlet: Optional[Sequence[bool]] = None,
        volumes: Literal["number_density", "fixed"] = "number_density",
        nu: float = 0.0,
        rho: float = 1.0,
        scheme: Literal["rotational", "incremental", "non_incremental"] = "rotational",
        viscous_theta: float = 0.5,
        gravity: Optional[Sequence[float]] = None,
        allowed_floating: int = 1,
        solve: Optional[Dict[str, Any]] = None,
    ) -> None: ...
    @property
    def dim(self) -> int: ...
    def __len__(self) -> int:
        """The caller's particles (ghosts excluded)."""
    @property
    def n_ghosts(self) -> int: ...
    @property
    def h(self) -> float: ...
    @property
    def n_pairs(self) -> int: ...
    @property
    def rebuilds(self) -> int:
        """Times the neighbour candidates were searched."""
    @property
    def x(self) -> FloatArray:
        """Positions ``(n, dim)`` (a copy; assign to move the particles)."""
    @x.setter
    def x(self, value: ArrayLike) -> None: ...
    @property
    def u(self) -> FloatArray:
        """Velocities ``(n, dim)`` (a copy)."""
    @u.setter
    def u(self, value: ArrayLike) -> None: ...
    @property
    def p(self) -> FloatArray:
        """Pressures ``(n,)`` (a copy)."""
    @p.setter
    def p(self, value: ArrayLike) -> None: ...
    @property
    def vol(self) -> FloatArray:
        """Volumes ``(n,)`` (a copy)."""
    @vol.setter
    def vol(self, value: ArrayLike) -> None: ...
    @property
    def capture(self) -> bool:
        """Keep the projection's inputs for :meth:`Recorder.record` (re-runnable records)."""
    @capture.setter
    def capture(self, on: bool) -> None: ...
    def update_neighbors(self) -> bool:
        """Brings the configuration up to date after the particles moved: positions confined
        to the domain, ghosts placed (re-made when the list searches again), neighbour list,
        volumes. Returns True when the candidates were searched again.

        Raises:
            InputError: NaN/Inf positions (naming the particle), a particle outside a wall.
        """
    def predict(self, dt: float, accel: Optional[ArrayLike] = None) -> FloatArray:
        """The predictor velocity ``u*`` (shape ``(n, dim)``): viscous term, ``−∇pⁿ/ρ``
        (incremental schemes), gravity and your ``accel`` (per particle). The particles are not
        changed. Move them with ``u*``, call :meth:`update_neighbors`, then :meth:`project`.

        Raises:
            InputError: ``dt`` not positive, NaN/Inf in ``u`` or ``accel`` (naming the
                particle), a wrong shape.
            ConnectivityError: before the implicit viscous solve.
        """
    def project(self, dt: float, u_star: ArrayLike) -> StepReport:
        """Projects ``u_star`` on the current configuration: checks (connectivity, ``c0``),
        the Poisson solve, the correction of ``u`` and the update of ``p``. On error ``u`` and
        ``p`` are unchanged.

        Raises:
            InputError: ``dt`` not positive, NaN/Inf in ``u_star`` (naming the particle), a
                neighbour list out of date (call :meth:`update_neighbors`).
            ConnectivityError: particles cut off (``offending`` lists them).
            SolveError: the linear solve failed.
        """
    def step(self, dt: float, accel: Optional[ArrayLike] = None) -> StepReport:
        """:meth:`predict` and :meth:`project` on the same configuration (particles that do not
        move during the step)."""
    def reset_pressure(self) -> None:
        """Zero pressure and held increment (after a one-off projection)."""
    def wrap(self, x: FloatArray) -> None:
        """Maps positions into the periodic box in place (float64 ``(n, dim)``), exactly as
        gpm's Rust loop does; a no-op without periodic axes."""

class Recorder:
    """An MCAP recording of your own loop (gpm's ``Recorder::record``): ``/config`` once,
    ``/diagnostics`` per step, and at level ``"full"`` every ``every`` steps a particle
    snapshot and (with ``System.capture``) the projection's inputs. Readable by ``gpm replay``
    and the Python ``mcap`` package. The file is written as ``path.partial`` and renamed by
    :meth:`finish` (or on leaving a ``with`` block; a block that raised leaves
    ``run.failed.mcap``, gpm's convention for a failed run).

    Raises:
        RecordError: the file cannot be created (naming it).
        InputError: an unknown level, ``every = 0``, a config that is not JSON.
    """

    def __init__(
        self,
        path: Union[str, PathLike[str]],
        level: Literal["none", "diagnostics", "full"] = "diagnostics",
        every: int = 1,
        config: Any = None,
    ) -> None: ...
    def wants_snapshot(self, step: int) -> bool:
        """Whether step ``step`` gets a snapshot (steps 1, k+1, 2k+1, … at level full)."""
    def record(self, system: System, report: StepReport, step: int, time: float) -> None:
        """Records step ``step`` (from 1) ending at ``time``: the report, and at snapshot steps
        the particles and the captured projection."""
    def finish(self) -> Dict[str, Any]:
        """Finishes the file; returns ``steps``, ``messages`` per topic, ``bytes``, ``path``."""
    @property
    def path(self) -> str: ...
    def __enter__(self) -> Recorder: ...
    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> bool:
        """Finishes the file; if the block raised, keeps it as ``run.failed.mcap`` instead."""
