# Set-up from scratch on a fresh machine: `make demo` (a paper case with figures), `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
PIP     = $(VENV)/bin/pip
OUT    ?= out

.PHONY: install demo paper test test-full bench docs clean system-deps petsc cholmod

$(VENV)/.installed: pyproject.toml
	$(MAKE) system-deps
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -e ".[test]"
	@# CHOLMOD (SuiteSparse 7 built below, scikit-sparse 0.5 against it); SciPy's SuperLU otherwise
	$(MAKE) cholmod || echo "CHOLMOD not built: using SciPy's SuperLU"
	$(PY) -c "import nitsche.linalg as l; print('linear solver:', l.describe())"
	touch $@

install: $(VENV)/.installed

# What SuiteSparse's build needs: CMake, C and C++ compilers, OpenBLAS (CHOLMOD's factorizations
# about 2x faster than with the reference BLAS; its LAPACK for SPQR), where the machine allows
# (root or sudo)
system-deps:
	@if command -v cmake >/dev/null 2>&1 && command -v g++ >/dev/null 2>&1 && \
	   ls /usr/lib/*/libopenblas.so >/dev/null 2>&1; then exit 0; fi; \
	if command -v apt-get >/dev/null 2>&1; then \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO="sudo -n"; \
	  ($$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq cmake g++ libopenblas-dev >/dev/null) \
	  || echo "could not install CMake / g++ / OpenBLAS: SciPy's solver or the reference BLAS"; \
	fi

# CHOLMOD with single-precision factors (nitsche.linalg: the preconditioner of the large
# levels' CG) needs SuiteSparse 7.4 or later; Debian bookworm has 5.12.  SuiteSparse's source
# as Debian trixie ships it (its checksum checked), built with CMake into $(VENV)/suitesparse
# (the libraries scikit-sparse links: CHOLMOD and AMD, CAMD, COLAMD, CCOLAMD, BTF, KLU, UMFPACK,
# SPQR; a few minutes on 2 cores), then scikit-sparse 0.5 from its source against it (rpath
# to that prefix; its factors kept supernodal, below).  The build tree is removed afterwards.
SUITESPARSE_VERSION ?= 7.10.1
SUITESPARSE_SHA256 ?= f33dc4dbbaa16711861bb986604ac7ea15d949276951c706c6997d5567cebfcc
SUITESPARSE_URL ?= http://deb.debian.org/debian/pool/main/s/suitesparse/suitesparse_$(SUITESPARSE_VERSION)+dfsg.orig.tar.xz
SUITESPARSE_PROJECTS = suitesparse_config;amd;camd;colamd;ccolamd;btf;klu;cholmod;umfpack;spqr
SUITESPARSE_PREFIX = $(abspath $(VENV))/suitesparse
SUITESPARSE_BUILD = $(abspath $(VENV))/build-suitesparse
SCIKIT_SPARSE_VERSION ?= 0.5.0
SCIKIT_SPARSE_SOURCE = $(SUITESPARSE_BUILD)/scikit_sparse-$(SCIKIT_SPARSE_VERSION)
$(VENV)/.cholmod-installed:
	rm -rf $(SUITESPARSE_BUILD) && mkdir -p $(SUITESPARSE_BUILD)/src
	$(PY) -c "import hashlib, sys, urllib.request; data = urllib.request.urlopen(sys.argv[1]).read(); \
	  digest = hashlib.sha256(data).hexdigest(); \
	  sys.exit(f'{sys.argv[1]}: sha256 {digest}, expected {sys.argv[2]}') if digest != sys.argv[2] else None; \
	  open(sys.argv[3], 'wb').write(data)" $(SUITESPARSE_URL) $(SUITESPARSE_SHA256) $(SUITESPARSE_BUILD)/src.tar.xz
	tar xJf $(SUITESPARSE_BUILD)/src.tar.xz -C $(SUITESPARSE_BUILD)/src --strip-components=1
	cmake -S $(SUITESPARSE_BUILD)/src -B $(SUITESPARSE_BUILD)/build -DCMAKE_BUILD_TYPE=Release \
	  -DCMAKE_INSTALL_PREFIX=$(SUITESPARSE_PREFIX) -DSUITESPARSE_ENABLE_PROJECTS="$(SUITESPARSE_PROJECTS)" \
	  -DSUITESPARSE_USE_CUDA=OFF -DSUITESPARSE_USE_FORTRAN=OFF -DSUITESPARSE_USE_64BIT_BLAS=OFF -DSUITESPARSE_USE_OPENMP=OFF \
	  -DBLA_VENDOR=OpenBLAS -DBUILD_STATIC_LIBS=OFF -DSUITESPARSE_DEMOS=OFF -DBUILD_TESTING=OFF > $(SUITESPARSE_BUILD)/cmake.log
	cmake --build $(SUITESPARSE_BUILD)/build -j $$(nproc) > $(SUITESPARSE_BUILD)/build.log
	cmake --install $(SUITESPARSE_BUILD)/build > $(SUITESPARSE_BUILD)/install.log
	$(PIP) download -q --no-cache-dir --no-deps --no-binary scikit-sparse "scikit-sparse==$(SCIKIT_SPARSE_VERSION)" \
	  -d $(SUITESPARSE_BUILD)
	tar xzf $(SUITESPARSE_BUILD)/scikit_sparse-$(SCIKIT_SPARSE_VERSION).tar.gz -C $(SUITESPARSE_BUILD)
	@# scikit-sparse 0.5's factorize turns a supernodal factor into a simplicial one (CHOLMOD's
	@# final_super = false): a copy in a larger form (an index per entry) made while the
	@# supernodal one is held, and slower solves; kept supernodal instead, as CHOLMOD makes it
	sed -i 's/self._cm.final_super = False/self._cm.final_super = True/' $(SCIKIT_SPARSE_SOURCE)/src/sksparse/cholmod.pyx
	grep -q "self._cm.final_super = True" $(SCIKIT_SPARSE_SOURCE)/src/sksparse/cholmod.pyx
	SUITESPARSE_INCLUDE_DIR=$(SUITESPARSE_PREFIX)/include/suitesparse SUITESPARSE_LIBRARY_DIR=$(SUITESPARSE_PREFIX)/lib \
	  LDFLAGS="-Wl,-rpath,$(SUITESPARSE_PREFIX)/lib" \
	  $(PIP) install -q --no-cache-dir --force-reinstall --no-deps $(SCIKIT_SPARSE_SOURCE)
	$(PY) -c "import sksparse.cholmod, nitsche.linalg as l; assert l.HAVE_CHOLMOD, 'scikit-sparse >= 0.5 not importable'"
	rm -rf $(SUITESPARSE_BUILD)
	touch $@

cholmod: $(VENV)/.cholmod-installed

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

# the peers of the benchmarks (NGSolve, matplotlib): pip install -e ".[bench]"
$(VENV)/.bench-installed: $(VENV)/.installed pyproject.toml
	$(PIP) install -q -e ".[bench]"
	touch $@

bench: install $(VENV)/.bench-installed
	$(PY) benchmarks/obstacle_assembly.py

# the API reference, generated from the docstrings (docs/api), warnings as errors: $(OUT)/docs/index.html
$(VENV)/.docs-installed: $(VENV)/.installed pyproject.toml
	$(PIP) install -q -e ".[docs]"
	touch $@

docs: install $(VENV)/.docs-installed
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs/api $(OUT)/docs

clean:
	rm -rf $(VENV) $(OUT) *.egg-info
