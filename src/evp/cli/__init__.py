"""The ``evp`` command line: one module per command group, assembled by :mod:`evp.cli.app`.

``main`` is here because it is the entry point pyproject.toml names (``evp = evp.cli:main``).
"""

import os

# One thread a BLAS call, unless the user chose otherwise: EVP's matrices are small (a bundle
# adjustment's reduced camera system has a few hundred unknowns) and its own threads and processes
# are the parallelism. OpenBLAS's threads on top of them made each factorisation wait for the
# others: a 276x276 Cholesky took 0.4-0.6 s on two busy cores against 1 ms on one thread, and the
# bundled sample runs 22-27 % faster on one (docs/decisions.md). Set before NumPy loads OpenBLAS;
# the station's and the batch engine's child processes inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# FFmpeg's own log (quiet, unless the user chose a level): a corrupt video printed "moov atom not
# found" on stdout, beside EVP's one line on stderr that names the file and what to do (AV_LOG_QUIET = -8)
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

from evp.cli.app import main  # noqa: E402

__all__ = ["main"]
