# fenics-adaptive on the official DOLFINx image.
#
# The image brings DOLFINx 0.11.0 (real PETSc, MPICH), Python 3.12, numpy, mpi4py and petsc4py.
# The native install (scripts/install.sh) takes the same DOLFINx release from the
# dolfinx-solver-real wheel pinned in requirements/native.txt. Every other dependency comes from
# requirements/common.txt, the file native.txt includes, under the constraints of
# requirements/lock.txt (everything they bring, pinned), so both installs get the same versions.
# gmsh: the image's own if it has one, else the pinned wheel (requirements/gmsh.txt) with the
# libraries it links against; never both. tests/test_packaging.py checks that these stay in step.
#
#   docker build -t fenics-adaptive .
#   docker run --rm -v "$PWD/results:/results" fenics-adaptive
#
# writes the main demo's results to ./results/esl_cantilever. docs/docker.md says more.
# Units: N, mm, s, tonne.
#
# The same image is published as docker.io/dolfinx/dolfinx:v0.11.0.
FROM ghcr.io/fenics/dolfinx/dolfinx:v0.11.0

ENV PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore

# python3 and pip are those of the image's virtual environment (/dolfinx-env, first on PATH),
# where DOLFINx's Python packages live.
WORKDIR /opt/fenics-adaptive
COPY requirements/ requirements/
RUN python3 -m pip install --no-cache-dir -c requirements/lock.txt \
        -r requirements/common.txt -r requirements/docs.txt
RUN if python3 -c 'import gmsh' 2>/dev/null; then \
        echo "gmsh: the image's own, $(python3 -c 'import gmsh; print(gmsh.__version__)')"; \
    else \
        apt-get update \
        && apt-get install -y --no-install-recommends \
            libglu1-mesa libxcursor1 libxft2 libxinerama1 libxrender1 \
        && rm -rf /var/lib/apt/lists/* \
        && python3 -m pip install --no-cache-dir -c requirements/lock.txt -r requirements/gmsh.txt; \
    fi
COPY . .
RUN python3 -m pip install --no-cache-dir --no-deps . \
    && cd / \
    && python3 -c 'from mpi4py import MPI; import dolfinx, numba, gmsh, matplotlib, fenics_adaptive'

# The tests start MPI runs with the mpiexec next to the Python interpreter, where the native
# install's mpich wheel puts it. The image's MPICH is in /usr/local/bin: link it there.
RUN bin=$(python3 -c 'import os, sys; print(os.path.dirname(sys.executable))') \
    && if [ ! -e "$bin/mpiexec" ]; then ln -s "$(command -v mpiexec)" "$bin/mpiexec"; fi

# Builds the main demo's mesh and compiles its forms once, so that the DOLFINx JIT cache
# (/root/.cache/fenics) is in the image and each run starts at once.
RUN fenics-adaptive check demos/esl_cantilever.toml

WORKDIR /results
CMD ["python3", "/opt/fenics-adaptive/demos/esl_cantilever.py", "--out", "/results/esl_cantilever"]
