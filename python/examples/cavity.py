"""The lid-driven cavity (Re 100, 50 × 50 particles) run by gpm from Python, plotted with
matplotlib against Ghia, Ghia & Shin (1982).

    python examples/cavity.py                       # Re 100, n = 50 (a few seconds)
    python examples/cavity.py --re 1000 --n 100     # any key of `gpm run cavity --config`
    python examples/cavity.py --out cavity.png

The run is gpm's own driver (`gpm.run_scene`): it returns the summary (errors against Ghia,
steps, wall time) and the centre-line profiles as CSV text. Without matplotlib the example says
so and prints the numbers only.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np

import gpm

DATA = Path(__file__).resolve().parents[2] / "data"


def ghia(re: int, which: str):
    """Ghia's table (data/ghia1982_re{re}_{which}.csv) if this is a gpm checkout, else None."""
    path = DATA / f"ghia1982_re{re}_{which}.csv"
    if not path.exists():
        return None
    return np.genfromtxt(path, delimiter=",", comments="#", names=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--re", type=float, default=100.0)
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--out", default="cavity_profiles.png", help="the plot (PNG)")
    args = ap.parse_args(argv)

    try:
        run = gpm.run_scene("cavity", {"re": args.re, "n": args.n})
    except gpm.GpmError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    s = run["summary"]
    print(f"cavity Re {s['re']:g}, n = {s['n']}: {s['steps']} steps in {s['wall_seconds']:.1f} s, "
          f"steady: {s['steady']}")
    for key in ("rms_u", "max_u", "rms_v", "max_v"):
        if s.get(key) is not None:
            print(f"  {key} against Ghia: {100 * s[key]:.2f} %")

    pu = np.genfromtxt(io.StringIO(run["tables"]["profile_u.csv"]), delimiter=",", names=True)
    pv = np.genfromtxt(io.StringIO(run["tables"]["profile_v.csv"]), delimiter=",", names=True)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot (pip install matplotlib); the numbers are above")
        return 0
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4.5))
    a.plot(pu["u"], pu["y"], label="gpm")
    b.plot(pv["x"], pv["v"], label="gpm")
    re = int(round(args.re))
    gu, gv = ghia(re, "u_vertical"), ghia(re, "v_horizontal")
    if gu is not None and gv is not None:
        a.plot(gu[gu.dtype.names[1]], gu[gu.dtype.names[0]], "o", mfc="none", label="Ghia et al. 1982")
        b.plot(gv[gv.dtype.names[0]], gv[gv.dtype.names[1]], "o", mfc="none", label="Ghia et al. 1982")
    a.set(xlabel="u", ylabel="y", title="u along x = 0.5")
    b.set(xlabel="x", ylabel="v", title="v along y = 0.5")
    for ax in (a, b):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(f"lid-driven cavity, Re {args.re:g}, {args.n}×{args.n} particles (gpm from Python)")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
