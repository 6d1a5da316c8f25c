#!/usr/bin/env python3
"""Reference generator for the steady 2D lid-driven cavity (independent of the crate's code).

Problem
    Unit square [0, 1]^2, lid y = 1 moving with u = U = 1 in +x, no slip on the other walls,
    Re = U L / nu.  Stream function / vorticity form of the steady Navier-Stokes equations:

        lap(psi) = -omega,
        u omega_x + v omega_y = (1/Re) lap(omega),
        u = psi_y,  v = -psi_x,  omega = v_x - u_y.

Boundary conditions
    psi = 0 on all walls.  Wall vorticity by Thom's formula,
        omega_w = -2 psi_adj / h^2 - 2 U_t / h,
    psi_adj the value at the first interior node along the wall normal and U_t the tangential
    wall speed (U on the lid, 0 elsewhere).  The four corner vorticities are not used by any
    interior stencil and are fixed to 0.
    With --lid-ramp D > 0 the lid moves with U S(x/D) S((1-x)/D), S(t) = 6t^5 - 15t^4 + 10t^3 on
    t clamped to [0, 1]: a lid whose speed falls smoothly to zero at both corners (D = 0.5: the
    regularised cavity), the profile of gpm's `lid_ramp` (`--lid-ramp` of the cavity example).

Discretisation
    Uniform grid with n intervals per side (n even, so that x = 0.5 and y = 0.5 are grid lines),
    nodes (i/n, j/n).  Five-point Laplacian and central first derivatives, i.e. the convection
    term as (Re/4)[(psi_N - psi_S)(om_E - om_W) - (psi_E - psi_W)(om_N - om_S)] after scaling.
    Unknowns [psi, omega] on all (n+1)^2 nodes; boundary psi and corner omega have identity rows.
    Equations scaled by h^2 (Poisson, Thom) and Re h^2 (transport).  The scheme is second order.

Solution
    Newton's method with the exact sparse Jacobian and a sparse LU (scipy splu, COLAMD), stopped
    when ||F||_2 / ||F_lid||_2 < tol (F_lid is the residual of the zero state, i.e. the lid
    forcing alone).  Starting guess: a bicubic-spline interpolation of a coarser solution, or the
    Stokes solution; when Newton from that guess fails, Reynolds-number continuation from Stokes
    (adaptive steps up to Re, each step started from the previous solution).

Sampling
    u = psi_y on x = 0.5 and v = -psi_x on y = 0.5 by central differences at the nodes (wall
    values from the boundary conditions), interpolated by a local 4-point cubic Lagrange
    interpolant to Ghia, Ghia & Shin (1982)'s printed point positions (Tables I and II, 17 points
    each including the walls; the wall values are the boundary values exactly).

Reference generation
    Grids solved in order, each from the previous one.  At each point f(h) = f0 + a h^2 + b h^3
    is solved through the three finest grids (R3 = f0, the tabulated value); R2 is the h^2-only
    extrapolation of the two finest grids, so R3 - R2 is the h^3 correction.  The error of R3
    comes from h^4 and higher terms that three grids cannot resolve point by point (they change
    sign along a profile where |R3 - R2| does not), so the uncertainty column is one value per
    profile: max(2 max_interior |R3 - R2|, 1e-6), and 0 at the walls.  At Re 1000 with grids
    128/256/512 it bounds the difference to a 256/512/1024 extrapolation at every point (the
    pointwise |R3 - R2| does not: 6.1e-6 against 0.4e-6 at y = 0.8516).

Sub-commands (run with -h for details)
    solve      one grid, JSON result on stdout
    reference  several grids + Richardson extrapolation, writes reference CSVs and a JSON
    compare    differences between two profile sets (reference CSVs, Ghia tables, JSON results)

Use one thread: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1.  Memory: about 2.4 GB at n = 512.
"""
import argparse
import datetime
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.interpolate import RectBivariateSpline
from scipy.optimize import brentq

# Ghia et al. (1982) point positions as printed (4 decimals), in table order.
GHIA_U_Y = (1.0000, 0.9766, 0.9688, 0.9609, 0.9531, 0.8516, 0.7344, 0.6172, 0.5000,
            0.4531, 0.2813, 0.1719, 0.1016, 0.0703, 0.0625, 0.0547, 0.0000)  # Table I, u on x = 0.5
GHIA_V_X = (1.0000, 0.9688, 0.9609, 0.9531, 0.9453, 0.9063, 0.8594, 0.8047, 0.5000,
            0.2344, 0.2266, 0.1563, 0.0938, 0.0781, 0.0703, 0.0625, 0.0000)  # Table II, v on y = 0.5

DEFAULT_TOL = 1e-10
DEFAULT_DATA = Path(__file__).resolve().parent.parent / "data"
UNCERTAINTY_FLOOR = 1e-6
UNCERTAINTY_FACTOR = 2.0
PROFILES = (("u", "u_vertical", "y"), ("v", "v_horizontal", "x"))  # (quantity, file stem, coordinate)


class ToolError(RuntimeError):
    """An expected failure (Newton did not converge, unreadable input): reported without a traceback."""


def log(msg):
    """Progress message on stderr (silenced by --quiet)."""
    if not log.quiet:
        print(msg, file=sys.stderr, flush=True)


log.quiet = False


def re_tag(re):
    """Reynolds number as used in file names: 1000.0 -> '1000', 1250.5 -> '1250.5'."""
    return str(int(re)) if float(re).is_integer() else repr(float(re))


def smooth_step(t):
    """S(t) = 6t^5 - 15t^4 + 10t^3 on t clamped to [0, 1]."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * t * (10.0 + t * (6.0 * t - 15.0))


def lid_profile(x, ramp):
    """The lid's speed over U at x: 1, or S(x/ramp) S((1-x)/ramp) for ramp > 0."""
    x = np.asarray(x, dtype=float)
    if ramp <= 0.0:
        return np.ones_like(x)
    return smooth_step(x / ramp) * smooth_step((1.0 - x) / ramp)


class Cavity:
    """Discrete stream-function/vorticity system on an n x n grid (see the module docstring)."""

    def __init__(self, n, U=1.0, ramp=0.0):
        """Grid with n intervals per side (n even), lid speed U and lid ramp width (0: the
        classic lid); assembles the linear part."""
        self.n, self.U, self.ramp = n, float(U), float(ramp)
        self.h = 1.0 / n
        self.m = n + 1
        self.N = self.m * self.m
        self.idx = np.arange(self.N).reshape(self.m, self.m)  # idx[i, j], i ~ x, j ~ y
        I, J = np.meshgrid(np.arange(self.m), np.arange(self.m), indexing="ij")
        self.interior = (I > 0) & (I < n) & (J > 0) & (J < n)
        self.corner = ((I == 0) | (I == n)) & ((J == 0) | (J == n))
        self.ii = self.idx[1:n, 1:n].ravel()
        self._build_linear()

    def _shift(self, di, dj):
        """Node indices of the interior nodes shifted by (di, dj)."""
        n = self.n
        return self.idx[1 + di:n + di, 1 + dj:n + dj]

    def _build_linear(self):
        """Assemble the Re-independent part: F(x) = A x + rhs + convection(x)."""
        n, N, h, idx, ii = self.n, self.N, self.h, self.idx, self.ii
        rows, cols, vals = [], [], []

        def add(r, c, v):
            """Append entries (rows r, columns c, values v broadcast to r's shape)."""
            rows.append(r)
            cols.append(c)
            vals.append(np.broadcast_to(np.asarray(v, dtype=float), r.shape))

        rhs = np.zeros(2 * N)
        # Poisson rows (h^2 scaled): psi_E + psi_W + psi_N + psi_S - 4 psi_P + h^2 omega_P = 0
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            add(ii, self._shift(di, dj).ravel(), 1.0)
        add(ii, ii, -4.0)
        add(ii, N + ii, h * h)
        # psi = 0 on the boundary, omega = 0 in the corners
        bb = idx[~self.interior]
        add(bb, bb, 1.0)
        cc = idx[self.corner]
        add(N + cc, N + cc, 1.0)
        # Thom rows (h^2 scaled): h^2 omega_w + 2 psi_adj - 2 psi_w + 2 U_t h = 0
        r = np.arange(1, n)
        walls = ((idx[r, 0], idx[r, 1], 0.0),          # bottom
                 (idx[0, r], idx[1, r], 0.0),          # left
                 (idx[n, r], idx[n - 1, r], 0.0),      # right
                 (idx[r, n], idx[r, n - 1], self.U * lid_profile(r * h, self.ramp)))   # lid
        for w, a, ut in walls:
            add(N + w, N + w, h * h)
            add(N + w, a, 2.0)
            add(N + w, w, -2.0)
            rhs[N + w] += 2.0 * ut * h
        # transport rows (Re h^2 scaled), diffusion part: five-point Laplacian of omega
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            add(N + ii, N + self._shift(di, dj).ravel(), 1.0)
        add(N + ii, N + ii, -4.0)
        self.A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                               shape=(2 * N, 2 * N))
        self.rhs = rhs
        self.lid_norm = np.linalg.norm(rhs)

    def _differences(self, x):
        """Central differences at the interior nodes: psi_N-psi_S, psi_E-psi_W, om_E-om_W, om_N-om_S."""
        n, m, N = self.n, self.m, self.N
        psi = x[:N].reshape(m, m)
        om = x[N:].reshape(m, m)
        return (psi[1:n, 2:] - psi[1:n, :-2], psi[2:, 1:n] - psi[:-2, 1:n],
                om[2:, 1:n] - om[:-2, 1:n], om[1:n, 2:] - om[1:n, :-2])

    def residual(self, x, re):
        """Scaled residual F(x) at Reynolds number re."""
        F = self.A @ x + self.rhs
        dpy, dpx, dox, doy = self._differences(x)
        F[self.N + self.ii] -= (re / 4.0) * (dpy * dox - dpx * doy).ravel()
        return F

    def relative_residual(self, x, re):
        """||F(x)||_2 / ||F_lid||_2."""
        return float(np.linalg.norm(self.residual(x, re)) / self.lid_norm)

    def jacobian(self, x, re):
        """Exact Jacobian dF/dx (CSC)."""
        N = self.N
        dpy, dpx, dox, doy = self._differences(x)
        c = re / 4.0
        r = np.tile(N + self.ii, 8)
        cols = np.concatenate([(N + self._shift(1, 0)).ravel(), (N + self._shift(-1, 0)).ravel(),
                               (N + self._shift(0, 1)).ravel(), (N + self._shift(0, -1)).ravel(),
                               self._shift(0, 1).ravel(), self._shift(0, -1).ravel(),
                               self._shift(1, 0).ravel(), self._shift(-1, 0).ravel()])
        vals = c * np.concatenate([-dpy.ravel(), dpy.ravel(), dpx.ravel(), -dpx.ravel(),
                                   -dox.ravel(), dox.ravel(), doy.ravel(), -doy.ravel()])
        Jc = sp.csr_matrix((vals, (r, cols)), shape=(2 * N, 2 * N))
        return (self.A + Jc).tocsc()

    def stokes(self):
        """Solution of the linear (Re = 0) problem."""
        return spla.splu(self.A.tocsc(), permc_spec="COLAMD").solve(-self.rhs)

    def newton(self, x0, re, tol, maxit):
        """Newton iteration from x0.

        Returns (x, status, relative residual, iterations); status is 'converged' (below tol),
        'stagnated' (below 1e-6 but no longer decreasing: round-off floor above tol), 'diverged'
        (non-finite, or 1e4 times the initial residual) or 'maxit'."""
        x = x0.copy()
        history = []
        while True:
            k = len(history)
            F = self.residual(x, re)
            rel = float(np.linalg.norm(F) / self.lid_norm)
            log(f"  n={self.n} Re={re:g} Newton it {k}: |F|/|F_lid| = {rel:.3e}")
            history.append(rel)
            if rel < tol:
                return x, "converged", rel, k
            if not np.isfinite(rel) or rel > 1e4 * max(history[0], 1.0):
                return x, "diverged", rel, k
            if k > 0 and rel < 1e-6 and rel > 0.5 * history[-2]:
                return x, "stagnated", rel, k
            if k == maxit:
                return x, "maxit", rel, k
            x = x + spla.splu(self.jacobian(x, re), permc_spec="COLAMD").solve(-F)

    def fields(self, x):
        """psi and omega as (n+1, n+1) arrays indexed [i, j]."""
        return x[:self.N].reshape(self.m, self.m), x[self.N:].reshape(self.m, self.m)

    def from_coarse(self, psi_c, om_c):
        """Bicubic-spline interpolation of a solution on another grid onto this grid."""
        xc = np.linspace(0.0, 1.0, psi_c.shape[0])
        xf = np.linspace(0.0, 1.0, self.m)
        psi = RectBivariateSpline(xc, xc, psi_c, kx=3, ky=3)(xf, xf)
        om = RectBivariateSpline(xc, xc, om_c, kx=3, ky=3)(xf, xf)
        psi[~self.interior] = 0.0
        om[self.corner] = 0.0
        return np.concatenate([psi.ravel(), om.ravel()])

    def psi_min(self, x):
        """Minimum of psi: node value and a local quadratic (3x3 stencil) refinement.

        Returns two dicts {value, x, y}: the minimum node and the stationary point of the
        quadratic Taylor fit around it."""
        psi, _ = self.fields(x)
        i, j = np.unravel_index(np.argmin(psi), psi.shape)
        h = self.h
        node = {"value": float(psi[i, j]), "x": float(i * h), "y": float(j * h)}
        P = psi[i - 1:i + 2, j - 1:j + 2]
        g = np.array([(P[2, 1] - P[0, 1]) / 2, (P[1, 2] - P[1, 0]) / 2])
        fxy = (P[2, 2] - P[2, 0] - P[0, 2] + P[0, 0]) / 4
        H = np.array([[P[2, 1] - 2 * P[1, 1] + P[0, 1], fxy], [fxy, P[1, 2] - 2 * P[1, 1] + P[1, 0]]])
        d = -np.linalg.solve(H, g)
        value = P[1, 1] + g @ d + 0.5 * d @ H @ d
        refined = {"value": float(value), "x": float((i + d[0]) * h), "y": float((j + d[1]) * h)}
        return node, refined

    def centrelines(self, x):
        """u(y) on x = 0.5 and v(x) on y = 0.5 at the nodes (central differences, wall values exact)."""
        psi, _ = self.fields(x)
        n, h, c = self.n, self.h, self.n // 2
        u = np.zeros(n + 1)
        v = np.zeros(n + 1)
        u[1:n] = (psi[c, 2:] - psi[c, :-2]) / (2 * h)
        u[n] = self.lid_centre()
        v[1:n] = -(psi[2:, c] - psi[:-2, c]) / (2 * h)
        return u, v

    def lid_centre(self):
        """The lid's speed at x = 0.5."""
        return float(self.U * lid_profile(0.5, self.ramp))

    def sample(self, x):
        """u at GHIA_U_Y on x = 0.5 and v at GHIA_V_X on y = 0.5 (walls: boundary values exactly)."""
        u, v = self.centrelines(x)
        nodes = np.linspace(0.0, 1.0, self.m)
        us = cubic_lagrange(nodes, u, np.array(GHIA_U_Y))
        vs = cubic_lagrange(nodes, v, np.array(GHIA_V_X))
        for pos, val, wall in ((GHIA_U_Y, us, {0.0: 0.0, 1.0: self.lid_centre()}), (GHIA_V_X, vs, {0.0: 0.0, 1.0: 0.0})):
            for k, p in enumerate(pos):
                if p in wall:
                    val[k] = wall[p]
        return us, vs


def cubic_lagrange(nodes, values, xq):
    """Local 4-point cubic Lagrange interpolation of values on uniform nodes at the points xq."""
    n = len(nodes) - 1
    h = nodes[1] - nodes[0]
    i0 = np.clip(np.floor(xq / h).astype(int) - 1, 0, n - 3)
    xs = nodes[i0[:, None] + np.arange(4)]
    fs = values[i0[:, None] + np.arange(4)]
    out = np.zeros(len(xq))
    for a in range(4):
        L = np.ones(len(xq))
        for b in range(4):
            if b != a:
                L *= (xq - xs[:, b]) / (xs[:, a] - xs[:, b])
        out += L * fs[:, a]
    return out


def check_stagnation(status, rel, tol, n, re):
    """Raise ToolError if Newton stopped at its round-off floor above the requested tolerance."""
    if status == "stagnated":
        raise ToolError(f"Newton stagnated at |F|/|F_lid| = {rel:.2e} > tol = {tol:g} on n={n}, Re={re:g} "
                         "(round-off floor): use a larger --tol")


def continuation(cav, re, tol):
    """Reynolds-number continuation from the Stokes solution up to re.

    Steps start at 100, double after each converged step (at most 1000) and are halved after a
    failed one.  Returns (x, stages) or raises ToolError."""
    x = cav.stokes()
    done, step, stages = 0.0, 100.0, []
    while done < re:
        target = min(re, done + step)
        xt, status, rel, its = cav.newton(x, target, tol, maxit=15)
        check_stagnation(status, rel, tol, cav.n, target)
        stages.append({"start": f"continuation Re={target:g}", "status": status, "iterations": its,
                       "residual": rel})
        if status == "converged":
            x, done, step = xt, target, min(2.0 * step, 1000.0)
        else:
            step /= 2.0
            if step < max(1.0, 1e-3 * re):
                raise ToolError(f"Newton did not converge on n={cav.n}: Reynolds-number continuation "
                                 f"stalled at Re={done:g} (failed for Re={target:g}, step {2 * step:g})")
    return x, stages


def solve_grid(n, re, tol=DEFAULT_TOL, init=None, ramp=0.0):
    """Solve on n intervals at Reynolds number re.

    init: None, or (psi, omega) arrays of another solution to interpolate as the starting guess.
    Newton from that guess (or from Stokes); if it fails, continuation from Stokes.
    ramp: the lid ramp width (0: the classic lid).
    Returns (cav, x, result) where result is a JSON-ready dict; raises ToolError on failure."""
    t0 = time.time()
    cav = Cavity(n, ramp=ramp)
    start = "interpolated" if init is not None else "Stokes"
    x0 = cav.from_coarse(*init) if init is not None else cav.stokes()
    x, status, rel, its = cav.newton(x0, re, tol, maxit=25)
    check_stagnation(status, rel, tol, n, re)
    stages = [{"start": start, "status": status, "iterations": its, "residual": rel}]
    if status != "converged":
        log(f"  n={n}: Newton from the {start} guess failed ({status}); continuation from Stokes")
        x, more = continuation(cav, re, tol)
        stages += more
    seconds = time.time() - t0
    node, refined = cav.psi_min(x)
    us, vs = cav.sample(x)
    result = {"re": re, "n": n, "lid_ramp": ramp, "converged": True, "residual": cav.relative_residual(x, re), "tol": tol,
              "newton": stages, "psi_min": {"node": node, "refined": refined},
              "u_vertical": {"y": list(GHIA_U_Y), "u": us.tolist()},
              "v_horizontal": {"x": list(GHIA_V_X), "v": vs.tolist()},
              "seconds": round(seconds, 2)}
    return cav, x, result


def extrapolate(h, f, powers):
    """Richardson extrapolation: solve f_k = f0 + sum_p c_p h_k^p (one row per grid) for f0.

    h: (k,) grid spacings, f: (k, npoints) values, powers: k-1 exponents.  Returns f0 (npoints,)."""
    M = np.column_stack([np.ones(len(h))] + [np.asarray(h) ** p for p in powers])
    return np.linalg.solve(M, np.asarray(f))[0]


def observed_order(h, f):
    """Order p through three grids: (f1 - f2)/(f2 - f3) = (h1^p - h2^p)/(h2^p - h3^p).

    Returns None where a difference vanishes (e.g. wall points), where the differences change
    sign (non-monotone convergence) or where no p in (0, 20) fits."""
    d1, d2 = f[0] - f[1], f[1] - f[2]
    if d1 == 0.0 or d2 == 0.0 or d1 / d2 < 0.0:
        return None
    q = d1 / d2
    r1, r2 = h[0] / h[1], h[1] / h[2]
    if math.isclose(r1, r2, rel_tol=1e-12):
        return math.log(q) / math.log(r1)

    def mismatch(p):
        """Difference ratio predicted by order p minus the observed one."""
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - q

    try:
        return brentq(mismatch, 1e-3, 20.0)
    except ValueError:
        return None


def orders_by_triple(grids, h, f):
    """Observed order per point for each consecutive grid triple: {'n1-n2-n3': [p or None, ...]}."""
    return {f"{grids[k]}-{grids[k + 1]}-{grids[k + 2]}":
            [observed_order(h[k:k + 3], f[k:k + 3, p]) for p in range(f.shape[1])]
            for k in range(len(grids) - 2)}


def extrapolate_profile(h, f, positions):
    """R3 (h^2, h^3 removed, three finest grids), R2 (h^2 removed, two finest) and the uncertainty.

    f: (grids, points) values at positions; wall points (0 or 1) keep their exact boundary value
    and get uncertainty 0.  Returns (R3, R2, uncertainty)."""
    r3 = extrapolate(h[-3:], f[-3:], (2, 3))
    r2 = extrapolate(h[-2:], f[-2:], (2,))
    wall = (positions == 0.0) | (positions == 1.0)
    r3[wall] = f[-1][wall]
    bound = max(UNCERTAINTY_FACTOR * np.abs(r3 - r2)[~wall].max(), UNCERTAINTY_FLOOR)
    return r3, r2, np.where(wall, 0.0, bound)


def load_init(path):
    """(psi, omega) from an .npz written by --save; ToolError if unusable."""
    try:
        with np.load(path) as d:
            psi, om = np.array(d["psi"]), np.array(d["om"])
    except (OSError, KeyError, ValueError) as e:
        raise ToolError(f"cannot read initial solution {path}: {e}") from None
    if psi.ndim != 2 or psi.shape[0] != psi.shape[1] or psi.shape != om.shape or psi.shape[0] < 5:
        raise ToolError(f"initial solution {path}: psi and om must be equal square arrays, "
                        f"got {psi.shape} and {om.shape}")
    return psi, om


def save_solution(path, cav, x, re):
    """Write the solution to an .npz (n, re, lid_ramp, psi, om), usable as --init."""
    psi, om = cav.fields(x)
    np.savez(path, n=cav.n, re=re, lid_ramp=cav.ramp, psi=psi, om=om)


def write_reference_csv(path, re, quantity, positions, values, uncertainty, method_line):
    """Write one profile in the data files' format (two '#' lines, header, rows in table order)."""
    if quantity == "u":
        line, table, header = "x=0.5", "I", "y,u,uncertainty"
    else:
        line, table, header = "y=0.5", "II", "x,v,uncertainty"
    title = (f"# Re={re_tag(re)} lid-driven cavity, {quantity} on {line} at Ghia (1982) Table {table} "
             "positions (as printed, 4 decimals)")
    lines = [title, method_line, header]
    lines += [f"{p:.4f},{v:.7f},{e:.1e}" for p, v, e in zip(positions, values, uncertainty)]
    Path(path).write_text("\n".join(lines) + "\n")


def cmd_solve(args):
    """solve: one grid, JSON on stdout."""
    init = load_init(args.init) if args.init else None
    cav, x, result = solve_grid(args.n, args.re, args.tol, init, args.lid_ramp)
    if args.save:
        save_solution(args.save, cav, x, args.re)
    print(json.dumps(result, indent=1))


def cmd_reference(args):
    """reference: grids in order, Richardson extrapolation, CSVs + JSON in --out."""
    t0 = time.time()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.save_dir:
        Path(args.save_dir).mkdir(parents=True, exist_ok=True)
    grids = args.grids
    per_grid, init = [], None
    for n in grids:
        log(f"Re={args.re:g}: solving n={n}")
        cav, x, res = solve_grid(n, args.re, args.tol, init, args.lid_ramp)
        log(f"Re={args.re:g}: n={n} done in {res['seconds']:.1f} s, "
            f"psi_min = {res['psi_min']['refined']['value']:.7f}")
        per_grid.append(res)
        init = cav.fields(x)
        if args.save_dir:
            save_solution(Path(args.save_dir) / f"fd_re{re_tag(args.re)}_n{n}.npz", cav, x, args.re)
        del cav, x
    h = np.array([1.0 / n for n in grids])
    g3, g2 = grids[-3:], grids[-2:]
    date = datetime.date.today().isoformat()
    lid = "" if args.lid_ramp == 0 else f", lid ramp {args.lid_ramp:g} (U S(x/D) S((1-x)/D))"
    method = (f"# 2nd-order FD stream-function/vorticity (Thom wall vorticity){lid}, Newton "
              f"(|F|/|F_lid| < {args.tol:g}), grids N={','.join(map(str, grids))}; value = Richardson "
              f"extrapolation removing h^2 and h^3 terms (N={','.join(map(str, g3))}); uncertainty = "
              f"max({UNCERTAINTY_FACTOR:g}*max_interior|value-R2({g2[0]},{g2[1]})|, 1e-6) per profile, "
              f"R2 = h^2-only extrapolation; generated {date} by fd_cavity.py reference")
    summary = {"re": args.re, "lid_ramp": args.lid_ramp, "grids": grids, "date": date, "tol": args.tol,
               "method": method[2:], "per_grid": per_grid}
    for quantity, stem, coord in PROFILES:
        positions = np.array(per_grid[0][stem][coord])
        f = np.array([r[stem][quantity] for r in per_grid])
        r3, r2, unc = extrapolate_profile(h, f, positions)
        path = out / f"extrapolated_re{re_tag(args.re)}_{stem}.csv"
        write_reference_csv(path, args.re, quantity, positions, r3, unc, method)
        log(f"wrote {path}")
        summary[stem] = {coord: positions.tolist(), quantity: r3.tolist(), f"{quantity}_R2": r2.tolist(),
                         "uncertainty": unc.tolist(), "observed_order": orders_by_triple(grids, h, f)}
    pm = np.array([[r["psi_min"]["refined"]["value"]] for r in per_grid])
    summary["psi_min_refined"] = {"per_grid": pm[:, 0].tolist(),
                                  "R3": float(extrapolate(h[-3:], pm[-3:], (2, 3))[0]),
                                  "R2": float(extrapolate(h[-2:], pm[-2:], (2,))[0]),
                                  "observed_order": {k: v[0] for k, v in
                                                     orders_by_triple(grids, h, pm).items()}}
    summary["seconds_total"] = round(time.time() - t0, 1)
    path = out / f"fd_re{re_tag(args.re)}.json"
    path.write_text(json.dumps(summary, indent=1) + "\n")
    log(f"wrote {path}")


def read_profile_csv(path):
    """(positions, values) of a two- or three-column CSV with '#' comments and a header line."""
    rows = []
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise ToolError(f"cannot read {path}: {e}") from None
    for line in text.splitlines():
        s = line.strip()
        if not s or s.startswith("#") or s[0].isalpha():
            continue
        try:
            rows.append([float(t) for t in s.split(",")[:2]])
        except ValueError:
            raise ToolError(f"{path}: not a number in line {line!r}") from None
    if not rows or any(len(r) < 2 for r in rows):
        raise ToolError(f"{path}: expected rows of at least two numbers (position, value)")
    a = np.array(rows)
    return a[:, 0], a[:, 1]


def load_profiles(spec, re, data_dir):
    """u and v profiles {'u': (y, u), 'v': (x, v)} from a profile source.

    spec: 'ghia' or 'extrapolated' (the tables for re in data_dir); a directory holding
    extrapolated_re{RE}_*.csv (else ghia1982_re{RE}_*.csv); one CSV of a u/v pair (the partner is
    found by swapping u_vertical/v_horizontal in the name); or a JSON written by solve or reference."""
    tag = re_tag(re)
    if spec in ("ghia", "extrapolated"):
        prefix = "ghia1982" if spec == "ghia" else "extrapolated"
        spec = str(Path(data_dir) / f"{prefix}_re{tag}_u_vertical.csv")
    p = Path(spec)
    if p.is_dir():
        for prefix in ("extrapolated", "ghia1982"):
            if (p / f"{prefix}_re{tag}_u_vertical.csv").exists():
                p = p / f"{prefix}_re{tag}_u_vertical.csv"
                break
        else:
            raise ToolError(f"{spec}: no extrapolated_re{tag}_*.csv or ghia1982_re{tag}_*.csv")
    if p.suffix == ".json":
        try:
            d = json.loads(p.read_text())
            return {q: (np.array(d[stem][c]), np.array(d[stem][q])) for q, stem, c in PROFILES}
        except (OSError, ValueError, KeyError) as e:
            raise ToolError(f"{p}: not a solve/reference JSON ({e})") from None
    if "u_vertical" in p.name:
        pu, pv = p, p.with_name(p.name.replace("u_vertical", "v_horizontal"))
    elif "v_horizontal" in p.name:
        pu, pv = p.with_name(p.name.replace("v_horizontal", "u_vertical")), p
    else:
        raise ToolError(f"{spec}: expected a directory, a .json, or a *u_vertical*/*v_horizontal* CSV")
    return {"u": read_profile_csv(pu), "v": read_profile_csv(pv)}


def cmd_compare(args):
    """compare: candidate minus reference at the common positions, JSON on stdout."""
    cand = load_profiles(args.candidate, args.re, args.data)
    ref = load_profiles(args.ref, args.re, args.data)
    result = {"re": args.re, "candidate": args.candidate, "ref": args.ref}
    for quantity, stem, coord in PROFILES:
        (pc, vc), (pr, vr) = cand[quantity], ref[quantity]
        common = sorted(set(np.round(pc, 4)) & set(np.round(pr, 4)), reverse=True)
        if not common:
            raise ToolError(f"no common {coord} positions for {quantity}")
        lc, lr = dict(zip(np.round(pc, 4), vc)), dict(zip(np.round(pr, 4), vr))
        diff = np.array([lc[p] - lr[p] for p in common])
        interior = np.array([0.0 < p < 1.0 for p in common])
        result[stem] = {"points": len(common), "interior_points": int(interior.sum()),
                        "max_abs_diff": float(np.max(np.abs(diff))),
                        "rms_interior_pct": float(100 * np.sqrt(np.mean(diff[interior] ** 2))),
                        "diff": [[float(p), float(e)] for p, e in zip(common, diff)]}
    print(json.dumps(result, indent=1))
    if args.max_diff is not None:
        worst = max(result[stem]["max_abs_diff"] for _, stem, _ in PROFILES)
        if worst >= args.max_diff:
            raise ToolError(f"largest difference {worst:.2e} is not below --max-diff {args.max_diff:g}")
        print(f"largest difference {worst:.2e} < --max-diff {args.max_diff:g}", file=sys.stderr)


def argument_type(convert, not_parsed, ok, not_ok):
    """An argparse type: convert(s), then ok(value); the messages are formats of s."""
    def parse(s):
        try:
            v = convert(s)
        except ValueError:
            raise argparse.ArgumentTypeError(not_parsed.format(s=s)) from None
        if not ok(v):
            raise argparse.ArgumentTypeError(not_ok.format(s=s))
        return v
    return parse


# a finite float > 0
positive_float = argument_type(float, "not a number: {s!r}", lambda v: math.isfinite(v) and v > 0,
                               "must be finite and > 0, got {s}")
# an even integer >= 8
grid_size = argument_type(int, "not an integer: {s!r}", lambda v: v >= 8 and v % 2 == 0,
                          "grid size must be an even integer >= 8, got {s}")
# a lid ramp width in [0, 0.5]
lid_ramp = argument_type(float, "lid ramp must be a number, got {s!r}", lambda v: 0.0 <= v <= 0.5,
                         "lid ramp must be within [0, 0.5], got {s}")


def build_parser():
    """The command-line interface."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Run '%(prog)s COMMAND -h' for each command's options.")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    solving = argparse.ArgumentParser(add_help=False)
    solving.add_argument("--re", type=positive_float, required=True, help="Reynolds number (> 0)")
    solving.add_argument("--tol", type=positive_float, default=DEFAULT_TOL,
                         help="Newton stopping test ||F||/||F_lid|| < TOL (default %(default)g)")
    solving.add_argument("--lid-ramp", type=lid_ramp, default=0.0, metavar="D",
                         help="the lid's speed falls smoothly to zero within D of each corner "
                              "(0 <= D <= 0.5; default 0: the classic lid; 0.5: the regularised cavity)")
    sub = ap.add_subparsers(dest="command", required=True)

    s = sub.add_parser("solve", parents=[common, solving], help="solve one grid, print JSON",
                       description="Solve on one grid; print JSON with psi_min, the centre-line values at "
                                   "Ghia's positions, convergence, residual and seconds.")
    s.add_argument("--n", type=grid_size, required=True, help="intervals per side (even, >= 8)")
    s.add_argument("--init", metavar="FILE.npz", help="start from this solution (from --save), interpolated")
    s.add_argument("--save", metavar="FILE.npz", help="save the solution (usable as --init)")
    s.set_defaults(func=cmd_solve)

    r = sub.add_parser("reference", parents=[common, solving], help="solve several grids and Richardson-extrapolate",
                       description="Solve the grids in order (each from the previous one), extrapolate with "
                                   "h^2 and h^3 removed through the three finest, and write "
                                   "OUT/extrapolated_re{RE}_{u_vertical,v_horizontal}.csv and "
                                   "OUT/fd_re{RE}.json.")
    r.add_argument("--grids", type=grid_size, nargs="+", default=[128, 256, 512], metavar="N",
                   help="increasing grid sizes, at least three (default: %(default)s)")
    r.add_argument("--out", required=True, help="output directory (created if missing)")
    r.add_argument("--save-dir", metavar="DIR",
                   help="also save each grid's solution as fd_re{RE}_n{N}.npz here")
    r.set_defaults(func=cmd_reference)

    c = sub.add_parser("compare", parents=[common], help="differences between two profile sets",
                       description="Candidate minus reference at the common positions: max |difference| "
                                   "(walls included) and RMS over the interior points in % of the lid "
                                   "speed. "
                                   "A source is 'ghia' or 'extrapolated' (tables in --data), a directory "
                                   "(extrapolated_re{RE}_*.csv, else ghia1982_re{RE}_*.csv), one CSV of a "
                                   "u_vertical/v_horizontal pair, or a JSON written by solve or reference.")
    c.add_argument("candidate", help="profiles to check")
    c.add_argument("--re", type=positive_float, required=True, help="Reynolds number (selects file names)")
    c.add_argument("--ref", default="extrapolated", help="reference profiles (default: %(default)s)")
    c.add_argument("--data", default=str(DEFAULT_DATA), help="data directory (default: %(default)s)")
    c.add_argument("--max-diff", type=positive_float, metavar="TOL",
                   help="exit with an error unless every |difference| is below TOL")
    c.set_defaults(func=cmd_compare)
    return ap


def main(argv=None):
    """Entry point: parse, validate, run; expected failures exit 1 with a message."""
    ap = build_parser()
    args = ap.parse_args(argv)
    log.quiet = args.quiet
    if args.command == "reference":
        if len(args.grids) < 3:
            ap.error("reference: --grids needs at least three grid sizes")
        if any(a >= b for a, b in zip(args.grids, args.grids[1:])):
            ap.error("reference: --grids must be strictly increasing")
    try:
        args.func(args)
    except ToolError as e:
        print(f"{ap.prog}: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
