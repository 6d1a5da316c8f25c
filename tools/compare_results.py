#!/usr/bin/env python3
"""Compares the `result` of two `gpm run` outputs (JSON printed on stdout): every number equal
to a relative tolerance (default 1e-7, with an absolute floor of 1e-12 for numbers at
round-off), every other value identical; wall-clock fields (keys with "seconds") skipped.

    tools/compare_results.py one_process.json mpirun.json [--tol 1e-7]

Exit status 0 when they agree, 1 (naming the first difference) otherwise. Used by `.ci/run`
to check that `mpirun -n 4 gpm run <scene>` reports what the single-process run reports.
"""
import json
import sys


def compare(a, b, path, tol, worst):
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return f"{path}: keys differ: {sorted(set(a) ^ set(b))}"
        errs = []
        for k in a:
            if "seconds" in k:
                continue
            err = compare(a[k], b[k], f"{path}.{k}", tol, worst)
            if err:
                errs.append(err)
        return "; ".join(errs) or None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}: lengths {len(a)} and {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            err = compare(x, y, f"{path}[{i}]", tol, worst)
            if err:
                return err
        return None
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool):
        d = abs(a - b)
        scale = max(abs(a), abs(b))
        if d > tol * scale + 1e-12:
            return f"{path}: {a} and {b} (relative difference {d / scale:.3e})"
        if scale > 1e-9:
            worst[0] = max(worst[0], d / scale)
        return None
    if a != b:
        return f"{path}: {a!r} and {b!r}"
    return None


def main():
    args = sys.argv[1:]
    tol = 1e-7
    if "--tol" in args:
        i = args.index("--tol")
        tol = float(args[i + 1])
        del args[i : i + 2]
    if len(args) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    try:
        a, b = (json.load(open(p))["result"] for p in args)
    except (OSError, ValueError, KeyError) as e:
        print(f"cannot read the results: {e}", file=sys.stderr)
        return 2
    worst = [0.0]
    err = compare(a, b, "result", tol, worst)
    if err:
        print(f"{args[0]} and {args[1]} differ: {err}", file=sys.stderr)
        return 1
    print(f"{args[1]}: every number within {worst[0]:.2e} relative of {args[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
