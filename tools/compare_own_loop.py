#!/usr/bin/env python3
"""Compares the /diagnostics of two own-loop recordings (the Rust example's and the Python or C
one's), read with the independent Python `mcap` package: the same /config, the same steps, and
every recorded number equal to REL (default 1e-12) relative.

Usage: compare_own_loop.py REFERENCE.mcap OTHER.mcap [REL]    exits non-zero on a difference.
"""

import json
import sys

from mcap.reader import make_reader

KEYS = ("div_before", "div_after", "c0", "stability_ratio", "kinetic_energy", "max_speed",
        "min_spacing", "correction_ratio")


def read(path):
    config, steps = None, []
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            data = json.loads(message.data)
            if channel.topic == "/config":
                config = data["config"]
            elif channel.topic == "/diagnostics":
                steps.append(data)
    return config, steps


def main():
    ref, other = sys.argv[1], sys.argv[2]
    tol = float(sys.argv[3]) if len(sys.argv) > 3 else 1e-12
    (c1, s1), (c2, s2) = read(ref), read(other)
    if c1 != c2:
        sys.exit(f"different /config: {c1} vs {c2}")
    if len(s1) != len(s2) or not s1:
        sys.exit(f"different step counts: {len(s1)} vs {len(s2)}")
    worst = 0.0
    for a, b in zip(s1, s2):
        if a["step"] != b["step"] or a["solve"]["iterations"] != b["solve"]["iterations"]:
            sys.exit(f"step {a['step']}: step numbers or solver iterations differ")
        for k in KEYS:
            rel = abs(a[k] - b[k]) / max(abs(a[k]), 1e-300)
            worst = max(worst, rel)
            if rel > tol:
                sys.exit(f"step {a['step']} {k}: {a[k]!r} vs {b[k]!r} ({rel:.1e} relative)")
    print(f"{other}: {len(s1)} steps, {len(KEYS)} quantities each, largest relative "
          f"difference to {ref}: {worst:.1e} (tolerance {tol:g})")


if __name__ == "__main__":
    main()
