"""Plugging the GPM projection into your own particle loop, from Python.

The same loop as gpm's Rust example ``examples/own_loop.rs``, number for number: a
Taylor–Green vortex on a 40 × 40 lattice in the periodic unit square, ν = 0.01, the
incremental scheme, a linear drag force ``-0.1 u`` of the user's own, 20 steps of
Δt = 0.002. The loop (positions, forces, advection) is the caller's; gpm predicts, projects on
the moved configuration and reports::

    for each step:
        sys.update_neighbors()                 # neighbours and volumes at xⁿ
        u_star = sys.predict(dt, accel=my_forces)
        x += dt * u_star; wrap                 # your advection
        sys.update_neighbors()                 # neighbours at x*
        report = sys.project(dt, u_star)

It prints the same table as ``cargo run --release --example own_loop``.

    python examples/own_loop.py              # the table
    python examples/own_loop.py --out DIR    # also DIR/run.mcap (snapshots every 5 steps)
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import List, Optional

import numpy as np

import gpm


def initial_particles(n: int):
    """The user's particles: the cell-centred n × n lattice (last axis fastest, as gpm's
    ``lattice``) with the Taylor–Green velocity, evaluated with the C library's sin/cos."""
    dx = 1.0 / n
    c = 0.0 + (np.arange(n) + 0.5) * dx
    gx, gy = np.meshgrid(c, c, indexing="ij")
    x = np.stack([gx.ravel(), gy.ravel()], axis=1)
    u = np.empty_like(x)
    for i, (px, py) in enumerate(x):
        s2x, c2x = math.sin(2.0 * math.pi * px), math.cos(2.0 * math.pi * px)
        s2y, c2y = math.sin(2.0 * math.pi * py), math.cos(2.0 * math.pi * py)
        u[i] = (-c2x * s2y, s2x * c2y)
    return x, u


def user_loop(
    n: int = 40,
    steps: int = 20,
    dt: float = 0.002,
    drag: float = 0.1,
    recorder: Optional[gpm.Recorder] = None,
) -> List[gpm.StepReport]:
    """Runs the loop; records each step when a recorder is given; returns every report."""
    dx = 1.0 / n
    x, u = initial_particles(n)
    h = 3.0 * dx
    sys_ = gpm.System(
        x,
        u,
        h=h,
        skin=0.3 * h,  # a skin, so that most updates only re-measure pairs
        weight="wendland2",
        boundary=gpm.Boundary.periodic([0.0, 0.0], [1.0, 1.0]),
        nu=0.01,
        scheme="incremental",
    )
    reports = []
    for k in range(1, steps + 1):
        # capture the projection's inputs only where the recorder takes a snapshot
        sys_.capture = recorder is not None and recorder.wants_snapshot(k)
        sys_.update_neighbors()
        # the user's own force: linear drag
        forces = -drag * sys_.u
        u_star = sys_.predict(dt, accel=forces)
        # the user's own advection with the predictor velocity, then the periodic wrap
        x = sys_.x
        x += dt * u_star
        sys_.wrap(x)
        sys_.x = x
        sys_.update_neighbors()
        report = sys_.project(dt, u_star)
        if recorder is not None:
            recorder.record(sys_, report, k, k * dt)
        reports.append(report)
    return reports


def rust_e(v: float, prec: int) -> str:
    """Rust's ``{:.prec e}``: ``1.234e-5`` (no ``+``, no leading zero in the exponent)."""
    m, e = f"{v:.{prec}e}".split("e")
    return f"{m}e{int(e)}"


def table(reports: List[gpm.StepReport]) -> str:
    lines = [
        f"{'step':>4} {'div before':>12} {'div after':>12} {'c0':>8} {'ratio':>10} {'KE':>10}"
    ]
    for k, r in enumerate(reports, start=1):
        lines.append(
            f"{k:>4} {rust_e(r.div_before, 3):>12} {rust_e(r.div_after, 3):>12} "
            f"{r.c0:>8.4f} {rust_e(r.stability_ratio, 3):>10} {r.kinetic_energy:>10.5f}"
        )
    return "\n".join(lines)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="also record DIR/run.mcap")
    args = ap.parse_args(argv)
    config = {"n": 40, "steps": 20, "dt": 0.002, "drag": 0.1}
    try:
        if args.out:
            os.makedirs(args.out, exist_ok=True)
            path = os.path.join(args.out, "run.mcap")
            with gpm.Recorder(path, level="full", every=5, config=config) as rec:
                reports = user_loop(**config, recorder=rec)
                summary = rec.finish()
            print(f"recorded {summary['steps']} steps to {path} ({summary['bytes']} bytes)")
            for note in summary["notes"]:
                print(f"note: {note}")
        else:
            reports = user_loop(**config)
    except gpm.GpmError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(table(reports))
    return 0


if __name__ == "__main__":
    sys.exit(main())
