#!/usr/bin/env python3
"""The peer run's table (markdown) and the two ratios of issue 17's targets, from peer.csv.

usage: summary.py peer.csv

Time for gpm to reach an error e* (its Lagrangian runs, errors from tools/peer/errors.py):
the runs (n, time, error) of one method are taken in the order of n; if the coarsest run is
already at or below e*, its time is used (an upper bound: a coarser run would be faster still);
otherwise the two consecutive runs whose errors bracket e* are joined by a straight line in
log(error)-log(time) and the time is read off it; if no run reaches e*, there is no ratio.
"""
import csv
import math
import sys


def time_to_reach(points, target):
    pts = sorted(points, key=lambda p: p[2])  # by n: the error falls with n
    if not pts:
        return None, 'no runs'
    if pts[0][1] <= target:
        return pts[0][0], f'coarsest run (n = {pts[0][2]}) already below: its time, an upper bound'
    for (t1, e1, n1), (t2, e2, n2) in zip(pts, pts[1:]):
        if e1 > target >= e2:
            s = math.log(t2 / t1) / math.log(e2 / e1)
            return t1 * (target / e1) ** s, f'log-log interpolation between n = {n1} and n = {n2}'
    return None, 'no gpm run reaches it'


def pct(v):
    return '' if v in ('', None) else f'{100 * float(v):.3g} %'


def secs(v):
    return '' if v in ('', None) else f'{float(v):.1f} s'


def main():
    rows = list(csv.DictReader(open(sys.argv[1])))
    print('| code | case | frame | method | n | wall time | CPU time | error u | error v | error | '
          'vs Ghia u / v | own error |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for r in sorted(rows, key=lambda r: (r['case'], r['code'], r['frame'], int(r['n']))):
        ghia = f"{pct(r['ghia_u'])} / {pct(r['ghia_v'])}" if r['ghia_u'] else ''
        print(f"| {r['code']} | {r['case']} | {r['frame']} | {r['method']} | {r['n']} | "
              f"{float(r['wall_seconds']):.1f} s | {secs(r.get('cpu_seconds'))} | {pct(r['error_u'])} | {pct(r['error_v'])} | "
              f"**{pct(r['error'])}** | {ghia} | {pct(r['own_error'])} |")
    print()
    for case, n_peer, factor in [('cavity', 50, 20), ('taylor_green', 100, 10)]:
        peer = [r for r in rows if r['code'] == 'pysph' and r['case'] == case
                and int(r['n']) == n_peer and r['error']]
        if not peer:
            print(f'{case}: no PySPH n = {n_peer} run')
            continue
        p = peer[0]
        e = float(p['error'])
        for key, what in [('wall_seconds', 'wall'), ('cpu_seconds', 'CPU')]:
            if not p.get(key):
                continue
            tp = float(p[key])
            methods = sorted({r['method'] for r in rows if r['code'] == 'gpm'
                              and r['case'] == case and r['frame'] == 'lagrangian'})
            for m in methods:
                gpm = [(float(r[key]), float(r['error']), int(r['n'])) for r in rows
                       if r['code'] == 'gpm' and r['case'] == case and r['method'] == m
                       and r['frame'] == 'lagrangian' and r['error'] and r.get(key)]
                t, how = time_to_reach(gpm, e)
                head = (f'{case}, {what} time: PySPH n = {n_peer} error {pct(e)} in {tp:.1f} s; '
                        f'gpm Lagrangian ({m})')
                if t is None:
                    print(f'{head}: {how}')
                    continue
                ratio = tp / t
                verdict = 'meets' if ratio >= factor else 'misses'
                print(f'{head} reaches it in {t:.1f} s ({how}): {ratio:.1f}x faster '
                      f'({verdict} the {factor}x target)')

if __name__ == '__main__':
    main()
