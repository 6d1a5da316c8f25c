#!/usr/bin/env python3
"""One independent error script for both codes of the peer run (issue 17, part 4).

Reads the final particle state of one run -- gpm's `particles.csv` (`x,y,u,v,p`, written by
the examples' `--particles-csv`) or PySPH's last output file (`.hdf5`/`.npz`, read with
`pysph.solver.utils.load`) -- and computes the errors with the same code for both:

* cavity (Re 100): the centre lines `u(x = 0.5, y)` and `v(x, y = 0.5)` are interpolated from
  the *fluid* particles of the final state at the 17 positions of Ghia et al. (1982), by
  quadratic moving least squares (basis 1, dx, dy, dx^2, dx dy, dy^2 about the target point,
  Wendland C2 weight (1-q)^4 (1+4q), support radius 3/n, no wall or ghost particles; exact for
  quadratic fields, so the interpolation error is O(dx^3) even one-sided at the walls).
  Error = RMS over the 15 interior positions (wall rows excluded, as `gpm::reference::rms_max`)
  of (interpolated - reference), in lid-speed units, for u and v, against the extrapolated
  reference `data/extrapolated_re100_*.csv` (`error_u`, `error_v`) and against Ghia's table
  (`ghia_u`, `ghia_v`). The combined `error` is the quadratic mean of the two,
  sqrt((error_u^2 + error_v^2)/2) (= the RMS over all 30 points).
* Taylor-Green (Re 100, U = 1, L = 1): at the particles, no interpolation,
  `error = sum_i |u_i - u_exact(x_i, t)| / sum_i |u_exact(x_i, t)|` (vector norms), `t` the
  time of the final state -- the definition of `gpm::scene::taylor_green::errors`
  (`l1_velocity_error`). `error_u`/`error_v` are the same sums per component.

Beside them, what each code reports itself (`own_*`): gpm's `summary.json`
(cavity: `rms_u_ref`, `rms_v_ref`, profiles averaged over the last window of the run;
Taylor-Green: `l1_velocity_error`); for PySPH its examples' post-processing recomputed here
(cavity: PySPH's `Interpolator` on all arrays over a 101 x 101 grid, averaged over the last 5
outputs, centre column/row read at the Ghia positions by linear interpolation, as
`pysph/examples/cavity.py` does; Taylor-Green: `mean| |u| - |u_exact| | / mean |u_exact|`, the
speed-magnitude L1 of `pysph/examples/taylor_green.py`).

usage: errors.py --code gpm|pysph --case cavity|tg --dir RUN_DIR [--data DATA_DIR]
prints one JSON object.
"""
import argparse
import glob
import json
import math
import os
import sys

import numpy as np


def read_table(path):
    rows = [l for l in open(path) if l.strip() and not l.startswith('#')]
    vals = [[float(c) for c in l.split(',')[:2]] for l in rows[1:]]
    return np.array(vals)


def wendland_c2(q):
    return np.where(q < 1.0, (1.0 - q) ** 4 * (1.0 + 4.0 * q), 0.0)


def mls_quadratic(xp, fp, targets, radius):
    """Quadratic MLS value of the particle values fp (at xp, shape (N, 2)) at each target."""
    out = np.empty(len(targets))
    for k, t in enumerate(targets):
        d = (xp - t) / radius
        q = np.hypot(d[:, 0], d[:, 1])
        m = q < 1.0
        dx, dy, w = d[m, 0], d[m, 1], wendland_c2(q[m])
        basis = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=1)
        if m.sum() < 10:
            basis = basis[:, :3]  # too few neighbours for a quadratic: linear
        a = basis.T @ (w[:, None] * basis)
        b = basis.T @ (w * fp[m])
        out[k] = np.linalg.solve(a, b)[0]
    return out


def rms_interior(pos, err):
    m = (pos > 0.0) & (pos < 1.0)
    return float(np.sqrt(np.mean(err[m] ** 2)))


def load_gpm(d):
    a = np.loadtxt(os.path.join(d, 'particles.csv'), delimiter=',', skiprows=1, ndmin=2)
    summary = json.load(open(os.path.join(d, 'summary.json')))
    t = summary.get('t_end')
    return a[:, 0:2], a[:, 2:4], t, summary


def pysph_files(d):
    from pysph.solver.utils import get_files
    files = get_files(d)
    if not files:
        raise SystemExit(f'no PySPH output in {d}')
    return files


def load_pysph(d):
    from pysph.solver.utils import load
    data = load(pysph_files(d)[-1])
    f = data['arrays']['fluid']
    x = np.stack([f.x, f.y], axis=1)
    u = np.stack([f.u, f.v], axis=1)
    return x, u, float(data['solver_data']['t']), data


def cavity_errors(x, u, n, data_dir):
    res = {}
    radius = 3.0 / n
    for label, comp, fname_ref, fname_ghia in [
        ('u', 0, 'extrapolated_re100_u_vertical.csv', 'ghia1982_re100_u_vertical.csv'),
        ('v', 1, 'extrapolated_re100_v_horizontal.csv', 'ghia1982_re100_v_horizontal.csv'),
    ]:
        ref = read_table(os.path.join(data_dir, fname_ref))
        ghia = read_table(os.path.join(data_dir, fname_ghia))
        assert np.allclose(ref[:, 0], ghia[:, 0])
        pos = ref[:, 0]
        targets = (np.stack([np.full_like(pos, 0.5), pos], axis=1) if label == 'u'
                   else np.stack([pos, np.full_like(pos, 0.5)], axis=1))
        inside = (pos > 0.0) & (pos < 1.0)
        vals = np.full_like(pos, np.nan)
        vals[inside] = mls_quadratic(x, u[:, comp], targets[inside], radius)
        res[f'error_{label}'] = rms_interior(pos, vals - ref[:, 1])
        res[f'ghia_{label}'] = rms_interior(pos, vals - ghia[:, 1])
    res['error'] = math.sqrt((res['error_u'] ** 2 + res['error_v'] ** 2) / 2)
    return res


def tg_exact(x, t, re=100.0):
    e = math.exp(-8.0 * math.pi ** 2 * t / re)
    ue = -e * np.cos(2 * math.pi * x[:, 0]) * np.sin(2 * math.pi * x[:, 1])
    ve = e * np.sin(2 * math.pi * x[:, 0]) * np.cos(2 * math.pi * x[:, 1])
    return np.stack([ue, ve], axis=1)


def tg_errors(x, u, t):
    ex = tg_exact(x, t)
    d = u - ex
    res = {
        'error': float(np.hypot(d[:, 0], d[:, 1]).sum() / np.hypot(ex[:, 0], ex[:, 1]).sum()),
        'error_u': float(np.abs(d[:, 0]).sum() / np.abs(ex[:, 0]).sum()),
        'error_v': float(np.abs(d[:, 1]).sum() / np.abs(ex[:, 1]).sum()),
    }
    return res


def pysph_own_cavity(d, data_dir, n_avg=5):
    """PySPH's cavity post-processing (pysph/examples/cavity.py, _plot_velocity)."""
    from pysph.solver.utils import load
    from pysph.tools.interpolator import Interpolator
    files = pysph_files(d)[-n_avg:]
    g = np.linspace(0, 1, 101)
    xx, yy = np.meshgrid(g, g)
    data = load(files[0])
    interp = Interpolator(list(data['arrays'].values()), x=xx, y=yy)
    ui = np.zeros_like(xx)
    vi = np.zeros_like(xx)
    for f in files:
        interp.update_particle_arrays(list(load(f)['arrays'].values()))
        ui += interp.interpolate('u').reshape(101, 101)
        vi += interp.interpolate('v').reshape(101, 101)
    ui /= len(files)
    vi /= len(files)
    res = {}
    for label, line, fname in [('u', ui[:, 50], 'extrapolated_re100_u_vertical.csv'),
                               ('v', vi[50], 'extrapolated_re100_v_horizontal.csv')]:
        ref = read_table(os.path.join(data_dir, fname))
        vals = np.interp(ref[:, 0], g, line)
        res[f'own_error_{label}'] = rms_interior(ref[:, 0], vals - ref[:, 1])
    res['own_error'] = math.sqrt((res['own_error_u'] ** 2 + res['own_error_v'] ** 2) / 2)
    res['own_method'] = 'PySPH Interpolator, mean of last 5 outputs'
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--code', choices=['gpm', 'pysph'], required=True)
    ap.add_argument('--case', choices=['cavity', 'tg'], required=True)
    ap.add_argument('--dir', required=True)
    ap.add_argument('--n', type=int, required=True, help='particles per side (dx = 1/n)')
    ap.add_argument('--data', default=os.path.join(os.path.dirname(__file__), '..', '..', 'data'))
    ap.add_argument('--no-own', action='store_true', help='skip the codes\' own errors')
    a = ap.parse_args()
    if a.code == 'gpm':
        x, u, t, extra = load_gpm(a.dir)
    else:
        x, u, t, extra = load_pysph(a.dir)
    out = {'particles': int(len(x)), 't_final': t}
    if a.case == 'cavity':
        out.update(cavity_errors(x, u, a.n, a.data))
    else:
        out.update(tg_errors(x, u, t))
    if not a.no_own:
        try:
            if a.code == 'gpm':
                s = extra
                if a.case == 'cavity':
                    out['own_error_u'], out['own_error_v'] = s['rms_u_ref'], s['rms_v_ref']
                    out['own_error'] = math.sqrt((s['rms_u_ref'] ** 2 + s['rms_v_ref'] ** 2) / 2)
                    out['own_method'] = 'gpm summary.json rms_*_ref (last-window mean)'
                else:
                    out['own_error'] = s['l1_velocity_error']
                    out['own_method'] = 'gpm summary.json l1_velocity_error'
                out['own_wall_seconds'] = s.get('wall_seconds')
            elif a.case == 'cavity':
                out.update(pysph_own_cavity(a.dir, a.data))
            else:
                ex = tg_exact(x, t)
                sp, spe = np.hypot(u[:, 0], u[:, 1]), np.hypot(ex[:, 0], ex[:, 1])
                out['own_error'] = float(np.mean(np.abs(sp - spe)) / np.mean(spe))
                out['own_method'] = 'PySPH taylor_green.py L1 of the speed'
        except Exception as e:  # the independent errors stand without the own ones
            out['own_error'] = None
            out['own_method'] = f'failed: {e!r}'
    json.dump(out, sys.stdout)
    print()


if __name__ == '__main__':
    main()
