"""The projection from Python: it removes divergence, and it gives the Rust example's numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

import gpm
from conftest import load_example, read_diagnostics


def divergent_field(n):
    """A periodic lattice with u = ∇ψ + rot, ψ = sin(2πx) sin(2πy)/(2π): plenty of divergence."""
    dx = 1.0 / n
    x = gpm.lattice([0.0, 0.0], [1.0, 1.0], dx)
    a, b = 2 * np.pi * x[:, 0], 2 * np.pi * x[:, 1]
    grad = np.stack([np.cos(a) * np.sin(b), np.sin(a) * np.cos(b)], axis=1)
    rot = np.stack([-np.cos(a) * np.sin(b), np.sin(a) * np.cos(b)], axis=1)
    return x, grad + rot, dx


def test_projection_cuts_the_divergence():
    x, u, dx = divergent_field(32)
    sys_ = gpm.System(
        x, u, h=3 * dx, boundary=gpm.Boundary.periodic([0, 0], [1, 1]), scheme="non_incremental"
    )
    assert len(sys_) == 32 * 32 and sys_.dim == 2 and sys_.n_ghosts == 0
    r = sys_.project(0.01, u)
    # the discrete divergence falls by more than a factor 20 (measured: ~1e-3 of it)
    assert r.div_after < 0.05 * r.div_before, (r.div_before, r.div_after)
    assert r.div_before > 1.0
    # Theorem 4.5 and one floating component (the periodic box)
    assert 0.0 < r.stability_ratio <= 1.0
    assert r.connectivity["floating"] == 1 and r.connectivity["isolated"] == 0
    assert r.c0 == pytest.approx(1.0, abs=1e-9)  # a uniform lattice is 1-semi-regular
    # the velocity changed by a gradient: the rotational part survives
    u_new = sys_.u
    assert np.all(np.isfinite(u_new)) and u_new.shape == (32 * 32, 2)
    a, b = 2 * np.pi * x[:, 0], 2 * np.pi * x[:, 1]
    rot = np.stack([-np.cos(a) * np.sin(b), np.sin(a) * np.cos(b)], axis=1)
    assert np.abs(u_new - rot).max() < 0.1
    # projecting the projected field starts from the divergence the first one left
    r2 = sys_.project(0.01, u_new)
    assert r2.div_before == pytest.approx(r.div_after, rel=1e-9)


def test_report_fields_and_dict():
    x, u, dx = divergent_field(16)
    sys_ = gpm.System(x, u, h=3 * dx, boundary=gpm.Boundary.periodic([0, 0], [1, 1]), nu=0.01)
    r = sys_.step(0.005)
    d = r.to_dict()
    for key in ("div_before", "div_after", "c0", "stability_ratio", "kinetic_energy"):
        assert d[key] == getattr(r, key)
    assert d["solve"]["unknowns"] == 16 * 16
    # the step's implicit viscous solve (ν > 0, θ = ½), over every particle
    assert r.viscous == d["viscous"]
    assert r.viscous["unknowns"] == 16 * 16 and r.viscous["rel_residual"] < 1e-10
    assert set(r.timings) >= {"diagnostics", "predictor", "source", "solve", "correction"}
    # kinetic energy ½ Σ ω |u|² from the arrays gpm hands back
    ke = 0.5 * np.sum(sys_.vol * np.sum(sys_.u**2, axis=1))
    assert r.kinetic_energy == pytest.approx(ke, rel=1e-12)
    # a projection alone runs none
    assert sys_.project(0.005, sys_.u).viscous is None


def test_identical_to_the_rust_example(rust_own_loop):
    """python/examples/own_loop.py against the recording of examples/own_loop.rs: every
    recorded quantity of every step equal to 1e-12 relative."""
    config, rust = read_diagnostics(rust_own_loop)
    cfg = config["config"]
    assert cfg == {"n": 40, "steps": 20, "dt": 0.002, "drag": 0.1}
    own_loop = load_example("own_loop")
    reports = own_loop.user_loop(**cfg)
    assert len(rust) == len(reports) == 20
    worst = 0.0
    for k, (r, py) in enumerate(zip(rust, reports), start=1):
        assert r["step"] == k
        for key in (
            "div_before", "div_after", "c0", "stability_ratio", "kinetic_energy",
            "max_speed", "min_spacing", "correction_ratio",
        ):
            a, b = r[key], getattr(py, key)
            rel = abs(a - b) / max(abs(a), 1e-300)
            worst = max(worst, rel)
            assert rel <= 1e-12, f"step {k} {key}: rust {a!r} python {b!r}"
        assert r["solve"]["iterations"] == py.solve["iters"]
        assert r["solve"]["unknowns"] == py.solve["unknowns"] == 40 * 40
    print(f"largest relative difference to the Rust example: {worst:.1e}")


def test_table_matches_rust_format():
    own_loop = load_example("own_loop")
    assert own_loop.rust_e(1.307e-1, 3) == "1.307e-1"
    assert own_loop.rust_e(4.481e-3, 3) == "4.481e-3"
    assert own_loop.rust_e(12346.0, 3) == "1.235e4"


def test_three_dimensions():
    n = 12
    dx = 1.0 / n
    x = gpm.lattice([0, 0, 0], [1, 1, 1], dx)
    a, b, c = (2 * np.pi * x[:, k] for k in range(3))
    # u = ∇(sin a sin b sin c) / 2π: all divergence
    u = np.stack([np.cos(a) * np.sin(b) * np.sin(c), np.sin(a) * np.cos(b) * np.sin(c),
                  np.sin(a) * np.sin(b) * np.cos(c)], axis=1)
    sys_ = gpm.System(x, u, h=2.5 * dx, boundary=gpm.Boundary.periodic([0, 0, 0], [1, 1, 1]),
                      scheme="non_incremental")
    assert sys_.dim == 3 and len(sys_) == n**3
    r = sys_.project(0.1, u)
    # coarse (k h ≈ 1.3): the GPM Laplacian and ∇̂h·∇h differ at O((k h)²); measured 0.16
    assert r.div_after < 0.25 * r.div_before, (r.div_before, r.div_after)
    assert r.stability_ratio <= 1.0
    assert sys_.u.shape == (n**3, 3)
    # the field was a gradient: most of it is removed (kinetic energy falls 5×)
    ke0 = 0.5 * np.sum(sys_.vol * np.sum(u**2, axis=1))
    assert r.kinetic_energy < 0.2 * ke0, (r.kinetic_energy, ke0)


def test_closed_box_makes_ghosts_and_keeps_the_theorem():
    n = 16
    dx = 1.0 / n
    x = gpm.lattice([0, 0], [1, 1], dx)
    u = np.zeros_like(x)
    u[:, 0] = x[:, 0]  # ∇·u = 1 inside a closed box
    sys_ = gpm.System(x, u, h=3 * dx, boundary=gpm.Boundary.closed_box([0, 0], [1, 1]),
                      scheme="non_incremental")
    assert sys_.n_ghosts > 0 and len(sys_) == n * n and sys_.x.shape == (n * n, 2)
    r = sys_.project(0.1, u)
    assert r.div_after < r.div_before
    assert r.stability_ratio <= 1.0 and r.connectivity["floating"] == 1


def test_lattice_matches_numpy():
    dx = 0.25
    x = gpm.lattice([0.0, 0.0], [1.0, 1.0], dx)
    c = (np.arange(4) + 0.5) * dx
    gx, gy = np.meshgrid(c, c, indexing="ij")
    assert np.array_equal(x, np.stack([gx.ravel(), gy.ravel()], axis=1))
    assert math.isclose(x[1, 1], 0.375)
