#!/usr/bin/env python3
"""Runs one of PySPH's own examples without its post-processing, so that the driver's timer
sees the simulation (start-up, run, output files) and not the plots.

usage: pysph_run.py cavity|taylor_green [the example's options...]
"""
import sys

# PySPH 1.0b2 turns mpi4py's automatic MPI_Init off when mpi4py is installed, and its shifting
# tool (pysph/sph/wc/shift.py) then calls an MPI reduction in serial runs too: without MPI_Init
# the run aborts. Initialising MPI here (one rank; the reduction is then the identity) leaves
# PySPH's code as it is.
import mpi4py

mpi4py.rc.initialize = True
from mpi4py import MPI  # noqa: E402,F401


def main():
    which, argv = sys.argv[1], sys.argv[2:]
    if which == 'cavity':
        from pysph.examples.cavity import LidDrivenCavity as App
    elif which == 'taylor_green':
        from pysph.examples.taylor_green import TaylorGreen as App
    else:
        raise SystemExit(f'unknown example {which}')
    App().run(argv)


if __name__ == '__main__':
    main()
