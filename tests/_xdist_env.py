"""A pytest-xdist worker's environment without its controller's MPI singleton (imported first).

Open MPI's singleton start (an MPI_Init without mpirun) puts its own variables into its
process's environment. pytest-xdist's controller imports ``conftest.py``, so MPI starts there,
and the workers it spawns inherit them: an ``mpirun`` that a test starts from a worker then took
itself for a rank of that singleton and ended at once with status 1 and no output. A worker
drops them before its own MPI starts, as a plain ``pytest`` process starts without them.
"""

from __future__ import annotations

import os

_PREFIXES = ("PMIX_", "OMPI_MCA_orte_", "OMPI_APP_CTX_")
_KEYS = ("OMPI_MCA_ess", "OMPI_MCA_pmix")

if "PYTEST_XDIST_WORKER" in os.environ:
    for key in list(os.environ):
        if key.startswith(_PREFIXES) or key in _KEYS:
            del os.environ[key]
