#!/usr/bin/env python3
"""Collects the peer run's records into one CSV and one work-precision plot (issue 17, part 4).

usage: plot.py RUNS.jsonl OUT_DIR   -> OUT_DIR/peer.csv, OUT_DIR/work_precision.png

Each line of RUNS.jsonl is one run: what `tools/peer/pysph.sh` knows (code, case, frame,
method, n, wall_seconds, command) merged with what `tools/peer/errors.py` printed.

peer.csv columns:
  code          gpm or pysph
  case          cavity (lid-driven, Re 100, steady state) or taylor_green (Re 100, t = 2)
  frame         lagrangian (particles move with the flow) or eulerian (fixed particles)
  method        the scheme (gpm: GPM projection; PySPH: TVF for the cavity, ISPH + shifting
                for Taylor-Green)
  n             particles per side (dx = 1/n)
  particles     fluid particles in the final state
  wall_seconds  wall-clock time of the whole process (start-up, run, its own output), measured
                by the driver script with the same timer for both codes
  cpu_seconds   CPU time of that process, user + system over all its threads (/usr/bin/time)
  error_u, error_v, error
                errors.py: cavity -- RMS of u on x = 0.5 / v on y = 0.5 against the
                extrapolated Re 100 reference (lid-speed units) and their quadratic mean;
                Taylor-Green -- L1 of the velocity at the particles, sum|u - u_ex| / sum|u_ex|
                (per component for error_u / error_v)
  ghia_u, ghia_v   cavity only: the same RMS against Ghia et al. (1982)
  own_error     what the code's own post-processing reports (see errors.py)
  own_wall_seconds  gpm only: the run time gpm itself reports (summary.json)
  t_final       time of the state the errors are computed on
  command       the command that was timed
"""
import csv
import json
import math
import os
import sys

COLUMNS = ['code', 'case', 'frame', 'method', 'n', 'particles', 'wall_seconds', 'cpu_seconds',
           'error_u',
           'error_v', 'error', 'ghia_u', 'ghia_v', 'own_error', 'own_wall_seconds', 't_final',
           'command']


def main():
    runs_path, out = sys.argv[1], sys.argv[2]
    runs = [json.loads(l) for l in open(runs_path) if l.strip()]
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, 'peer.csv'), 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in runs:
            w.writerow(['' if r.get(c) is None else r.get(c) for c in COLUMNS])
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes2 = plt.subplots(2, 2, figsize=(11, 9))
    styles = {
        ('gpm', 'lagrangian'): dict(color='C0', marker='o', ls='-'),
        ('gpm', 'eulerian'): dict(color='C2', marker='s', ls='--'),
        ('pysph', 'lagrangian'): dict(color='C3', marker='^', ls='-'),
    }
    titles = {'cavity': 'lid-driven cavity, Re 100\nRMS of u and v on the centre lines '
                        'vs the extrapolated reference',
              'taylor_green': 'Taylor\u2013Green, Re 100, t = 2\nL1 of the velocity vs the '
                              'exact solution'}
    panels = [(ax, case, key) for row, key in zip(axes2, ['wall_seconds', 'cpu_seconds'])
              for ax, case in zip(row, ['cavity', 'taylor_green'])]
    for ax, case, key in panels:
        groups = {}
        for r in runs:
            if r['case'] == case and r.get('error') is not None and r.get(key) is not None:
                groups.setdefault((r['code'], r['frame'], r['method']), []).append(r)
        for (code, frame, method), rs in sorted(groups.items()):
            rs.sort(key=lambda r: r['n'])
            st = dict(styles.get((code, frame), dict(marker='x')))
            if 't = 10' in method:
                st.update(ls=':', marker='D')
            label = f'{"gpm" if code == "gpm" else "PySPH"} {frame} ({method})'
            ax.loglog([r[key] for r in rs], [100 * r['error'] for r in rs],
                      label=label, **st)
            for r in rs:
                ax.annotate(f'n={r["n"]}', (r[key], 100 * r['error']),
                            textcoords='offset points', xytext=(5, 4), fontsize=8)
        ax.set_xlabel('wall time [s] (2 cores; see the README for the load)' if key == 'wall_seconds'
                      else 'CPU time, user + system, all threads [s]')
        ax.set_ylabel('error [%]')
        ax.set_title(titles[case], fontsize=10)
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'work_precision.png'), dpi=120)
    print(f'wrote {out}/peer.csv and {out}/work_precision.png')


if __name__ == '__main__':
    main()
