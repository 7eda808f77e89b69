"""The command-line programs (`slamlab`, `slamlab-report`, `slamlab-verify`, `slamlab-sim`).

Importing this package, which every program does before NumPy loads, keeps OpenBLAS to one
thread: its second thread busy-waits while NumPy starts, ~0.05 s CPU of every process
(NumPy's import 0.11 -> 0.06 s CPU on a 2-core machine). slamlab's matrix products are
small (poses, 3 x 3 frames, one scan's points), where OpenBLAS does not thread anyway, and
the heavy loops are numba kernels with their own threads. A value the user exported wins;
importing slamlab as a library (not through this package) leaves the setting alone.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
