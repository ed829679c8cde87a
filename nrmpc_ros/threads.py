"""One BLAS thread for the command line and the node, set before numpy is first imported.

The linear algebra here runs on many small matrices (3x3 point blocks, camera blocks of a few dozen
parameters): BLAS threads only add synchronisation, and on a busy machine they made the joint adjustment
several times slower. The entry points import this module first; a user's own setting of these variables
wins (``setdefault``), and library users keep whatever they configured.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
