# Set-up from scratch on a fresh machine: `make demo` (a paper case with figures), `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
PIP     = $(VENV)/bin/pip
OUT    ?= out

.PHONY: install demo paper test test-full bench docs clean system-deps petsc

$(VENV)/.installed: pyproject.toml
	$(MAKE) system-deps
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -e ".[test]"
	@# CHOLMOD (scikit-sparse < 0.5 builds against Debian's SuiteSparse 5); SciPy's SuperLU otherwise
	-$(PIP) install -q "scikit-sparse<0.5" || echo "scikit-sparse not installed: using SciPy's SuperLU"
	$(PY) -c "import nitsche.linalg as l; print('linear solver:', l.describe())"
	touch $@

install: $(VENV)/.installed

# Debian's SuiteSparse headers for CHOLMOD and OpenBLAS (CHOLMOD's factorizations about
# 2x faster than with the reference BLAS), where the machine allows (root or sudo)
system-deps:
	@if [ -f /usr/include/suitesparse/cholmod.h ] && \
	   ls /usr/lib/*/openblas*/libblas.so.3 >/dev/null 2>&1; then exit 0; fi; \
	if command -v apt-get >/dev/null 2>&1; then \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO="sudo -n"; \
	  ($$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libsuitesparse-dev libopenblas0-pthread >/dev/null) \
	  || echo "could not install libsuitesparse-dev / OpenBLAS: SciPy's solver or the reference BLAS"; \
	fi

# The distributed engine (mpirun -n N nitsche run CASE; nitsche.distributed): Debian's Open MPI,
# MUMPS 5.5 built with Scotch and PT-Scotch (libmumps-ptscotch-dev: libdmumps_ptscotch, next to
# libmumps-dev's plain libdmumps, whose orderings are AMD, AMF, QAMD and PORD only) and ScaLAPACK
# (built against that Open MPI; gfortran links their Fortran runtime), then mpi4py, pymetis, and
# PETSc + petsc4py built from PyPI's sources against them (about 10-15 minutes each on 2 shared
# cores; never a cached wheel, which may lack MUMPS); the tests in tests/test_distributed.py run
# once this is installed.  MUMPS makes `--solver direct` a factorization divided among the ranks
# (without it every rank factors the whole matrix), ordered by nested dissection (PT-Scotch).
MPI_PACKAGES = libopenmpi-dev openmpi-bin patchelf gfortran libmumps-ptscotch-dev libscalapack-openmpi-dev
PETSC_CONFIGURE_OPTIONS ?= --with-debugging=0 --with-fortran-bindings=0 --with-x=0 \
  --with-mumps-include=/usr/include \
  --with-mumps-lib=[-ldmumps_ptscotch,-lmumps_common_ptscotch,-lpord_ptscotch] \
  --with-scalapack-lib=-lscalapack-openmpi
PETSC_VERSION ?= 3.26.1
$(VENV)/.petsc-installed: $(VENV)/.installed
	@if ! command -v mpicc >/dev/null 2>&1 || ! command -v mpifort >/dev/null 2>&1 || \
	   ! command -v patchelf >/dev/null 2>&1 || ! ls /usr/lib/*/libdmumps_ptscotch.so >/dev/null 2>&1 || \
	   ! ls /usr/lib/*/libscalapack-openmpi.so >/dev/null 2>&1; then \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO="sudo -n"; \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq $(MPI_PACKAGES) >/dev/null; \
	fi
	$(PIP) install -q cython numpy "setuptools>=68" wheel
	MPICC=mpicc MPICXX=mpicxx MPIFORT=mpifort PETSC_CONFIGURE_OPTIONS="$(PETSC_CONFIGURE_OPTIONS)" \
	  $(PIP) install -q --no-build-isolation --no-cache-dir --force-reinstall --no-deps petsc==$(PETSC_VERSION)
	MPICC=mpicc $(PIP) install -q --no-build-isolation --no-cache-dir --force-reinstall --no-deps petsc4py==$(PETSC_VERSION)
	$(PIP) install -q -e ".[petsc]"
	$(PY) -c "from petsc4py import PETSc; from mpi4py import MPI; print('PETSc', PETSc.Sys.getVersion(), 'MUMPS:', PETSc.Sys.hasExternalPackage('mumps'), MPI.Get_library_version().splitlines()[0])"
	touch $@

petsc: $(VENV)/.petsc-installed

# every paper case, fast (about 2 minutes): figures and tables in $(OUT)/paper/index.md
demo: install
	$(VENV)/bin/nitsche paper --fast --out $(OUT)/paper

# the full reproduction (tens of minutes)
paper: install
	$(VENV)/bin/nitsche paper --out $(OUT)/paper-full

test: install
	$(VENV)/bin/pytest -q

test-full: install
	$(VENV)/bin/pytest -q --full

bench: install
	$(PY) benchmarks/obstacle_assembly.py

# the API reference, generated from the docstrings (docs/api), warnings as errors: $(OUT)/docs/index.html
$(VENV)/.docs-installed: $(VENV)/.installed pyproject.toml
	$(PIP) install -q -e ".[docs]"
	touch $@

docs: install $(VENV)/.docs-installed
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs/api $(OUT)/docs

clean:
	rm -rf $(VENV) $(OUT) *.egg-info
