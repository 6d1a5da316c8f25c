"""gpm — the checked generalized-particle-method projection for your own particle loop.

The caller owns the loop; gpm owns the neighbour list, the checks (h-connectivity, the
semi-regularity constant ``c0``, the Theorem 4.5 ratio) and the projection::

    import numpy as np, gpm

    n = 40; dx = 1.0 / n
    x = gpm.lattice([0, 0], [1, 1], dx)
    u = np.stack([-np.cos(2*np.pi*x[:, 0]) * np.sin(2*np.pi*x[:, 1]),
                  np.sin(2*np.pi*x[:, 0]) * np.cos(2*np.pi*x[:, 1])], axis=1)
    sys = gpm.System(x, u, h=3*dx, skin=0.9*dx, boundary=gpm.Boundary.periodic([0, 0], [1, 1]),
                     nu=0.01, scheme="incremental")
    u_star = sys.predict(0.002, accel=-0.1 * sys.u)   # your forces
    x = sys.x; x += 0.002 * u_star; sys.wrap(x); sys.x = x   # your advection
    sys.update_neighbors()
    report = sys.project(0.002, u_star)               # divergence removed on the moved particles
    assert report.div_after < report.div_before

See ``examples/own_loop.py`` (the same loop as gpm's Rust ``examples/own_loop.rs``) and
``examples/cavity.py`` (a ready-made scene).
"""

from __future__ import annotations

from ._errors import (
    ConnectivityError,
    GpmError,
    InputError,
    PairWeightError,
    RecordError,
    SolveError,
    StabilityError,
)
from ._gpm import (
    SCENES,
    Boundary,
    Recorder,
    StepReport,
    System,
    __version__,
    lattice,
    run_scene,
)

__all__ = [
    "SCENES",
    "Boundary",
    "ConnectivityError",
    "GpmError",
    "InputError",
    "PairWeightError",
    "RecordError",
    "Recorder",
    "SolveError",
    "StabilityError",
    "StepReport",
    "System",
    "__version__",
    "lattice",
    "run_scene",
]
