"""curve_formation: formation control of nonholonomic robots along parametric curves.

Importing the package before numpy (as every node process, the runner and the command line
do) gives numpy's BLAS one thread per process unless the environment says otherwise: the
nodes' matrices are small, and on a PC whose cores the node processes already fill, BLAS's
own threads wait for each other instead. Measured: a controller's check of a 50-robot curve
(an SVD of 100 x 102) took 0.4 ms alone and 242 ms with 12 node processes busy; 50 robots in
groups of five ticked at about 1 Hz, and at 9.35 Hz or more with one thread.
"""

import os


for _threads in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_threads, '1')


def version():
    """The installed package's version (setup.py, package.xml), or 'unknown' if not installed."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed
    try:
        return installed('curve_formation')
    except PackageNotFoundError:
        return 'unknown'
