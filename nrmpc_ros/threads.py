"""One BLAS thread and one OpenCV thread for the command line and the node, set before numpy and cv2 are first
imported.

The linear algebra here runs on many small matrices (3x3 point blocks, camera blocks of a few dozen
parameters): BLAS threads only add synchronisation, and on a busy machine they made the joint adjustment
several times slower. OpenCV's own thread pool splits each KLT pass, pyramid and corner search of one
640x480 image across the cores and keeps its workers spinning between calls: on two cores that cost a fifth
more CPU per image for no gain in wall time (docs/RESULTS.md, "OpenCV on one thread"), and the node has its
own two workers. The entry points import this module first; a user's own setting of these variables wins
(``setdefault``), and library users keep whatever they configured.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_var, "1")
