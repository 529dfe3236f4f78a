# shoulder-fem: the README's two commands are `make demo` and `make test`.
SHELL := /bin/bash
PY    := .venv/bin/python
# One thread per MPI rank (OpenBLAS with free threads is slower than reference BLAS here);
# Open MPI as root and with more ranks than cores.
export OMP_NUM_THREADS := 1
export OPENBLAS_NUM_THREADS := 1
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
# mpirun forwards SIGTERM to the ranks and kills them after this many seconds (Open MPI's
# default, 1, is too short for rank 0 to remove an unfinished output folder).
export OMPI_MCA_odls_base_sigkill_timeout := 10
MPIRUN := mpirun -n 2
DEMO_OUT ?= results/demo
LEVEL ?= coarse

.PHONY: setup demo test test-serial test-mpi bench lint clean

setup:
	@bash scripts/setup.sh

demo: setup
	@mkdir -p $(dir $(DEMO_OUT))
	$(PY) -m shoulder_fem.cli bench shoulder-internal-rotation --level $(LEVEL) --out $(DEMO_OUT) --force

# Each phase prints its slowest tests and its time. The serial phase runs on two worker
# processes (pytest-xdist; a module's tests sharing a module fixture stay on one worker:
# tests/conftest.py). Under mpirun the ranks agree on each test's outcome and a rank's failure
# is printed at once with its rank (tests/_lockstep.py).
# The tests that start mpirun themselves run in one plain process after it: from an xdist
# worker, test_lockstep's mpirun ended at once with status 1.
TEST_WORKERS ?= 2
OWN_MPIRUN := tests/test_lockstep.py tests/test_stop_guard.py \
  tests/test_cli.py::test_sigterm_under_mpirun_removes_the_unfinished_output \
  tests/test_cli.py::test_an_error_on_one_rank_aborts_the_job_instead_of_hanging
test: setup
	@t0=$$(date +%s); $(PY) -m pytest -q -rfE --durations=15 -n $(TEST_WORKERS) \
	  --dist loadgroup $(addprefix --deselect ,$(OWN_MPIRUN)) tests; \
	  rc=$$?; echo "make test: serial phase ($(TEST_WORKERS) workers) $$(( $$(date +%s) - t0 )) s, exit $$rc"; exit $$rc
	@t0=$$(date +%s); $(PY) -m pytest -q -rfE $(OWN_MPIRUN); \
	  rc=$$?; echo "make test: tests starting mpirun $$(( $$(date +%s) - t0 )) s, exit $$rc"; exit $$rc
	@t0=$$(date +%s); $(MPIRUN) $(PY) -m mpi4py -m pytest -q -rfE --durations=15 --color=no \
	  -m mpi -p no:cacheprovider tests; rc=$$?; \
	  echo "make test: mpirun -n 2 phase $$(( $$(date +%s) - t0 )) s, exit $$rc"; exit $$rc

bench: setup
	$(PY) benchmarks/spinning_bar.py --out benchmarks/results
	$(PY) benchmarks/stability_map.py --out benchmarks/results
	$(PY) benchmarks/speed_accuracy.py --out benchmarks/results
	$(PY) benchmarks/contact.py --out benchmarks/results
	$(PY) benchmarks/shoulder_bone_compliance.py --level coarse --out benchmarks/results

clean:
	rm -rf results .pytest_cache
