#!/usr/bin/env bash
# One-time, idempotent set-up on Debian 12 (bookworm): Debian's FEniCSx stack, OpenBLAS,
# Open MPI, then a virtual environment over the system site-packages with the project
# installed editable. A second run only checks and costs a few seconds.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(
  python3-dolfinx python3-petsc4py python3-mpi4py python3-ufl python3-ffcx python3-basix
  python3-gmsh python3-meshio python3-h5py python3-nibabel python3-pydicom python3-tqdm python3-cffi python3-pint
  openmpi-bin libopenblas0-openmp
  python3-numpy python3-scipy python3-matplotlib python3-pytest python3-pytest-timeout python3-pytest-xdist
  python3-venv python3-pip python3-setuptools
  gcc
)

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing Debian packages: ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

# The FEniCSx packages exist for Debian's interpreter only: build the venv from it.
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv from /usr/bin/python3 (system site-packages)"
  /usr/bin/python3 -m venv --system-site-packages .venv
fi

stamp=.venv/.shoulder-fem-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing shoulder-fem (editable, with test extras)"
  .venv/bin/python -m pip install -q --no-build-isolation --no-deps -e .
  .venv/bin/python -c "import pytest, pytest_timeout, xdist, numpy, scipy, matplotlib" 2>/dev/null \
    || .venv/bin/python -m pip install -q -e ".[test]"
  touch "$stamp"
fi

.venv/bin/python - <<'PY'
import dolfinx, petsc4py, mpi4py, gmsh, meshio  # noqa: F401  fail here, not in a test
PY
