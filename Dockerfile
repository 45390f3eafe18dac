# fenics-adaptive on the official DOLFINx image. The image brings DOLFINx 0.11.0, PETSc and MPI
# (the native install takes the same DOLFINx from the dolfinx-solver-real wheel); every other
# dependency comes from requirements/common.txt, the same pins scripts/install.sh uses.
#
#   docker build -t fenics-adaptive .
#   docker run --rm -v "$PWD/results:/results" fenics-adaptive
#
# writes the main demo's results to ./results/esl_cantilever. Units: N, mm, s, tonne.
FROM ghcr.io/fenics/dolfinx/dolfinx:v0.11.0

# shared libraries the gmsh wheel links against
RUN apt-get update \
    && apt-get install -y --no-install-recommends \
        libglu1-mesa libxcursor1 libxft2 libxinerama1 libxrender1 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/fenics-adaptive
COPY requirements/ requirements/
RUN python3 -m pip install --no-cache-dir -r requirements/common.txt
COPY . .
RUN python3 -m pip install --no-cache-dir --no-deps .

WORKDIR /results
CMD ["python3", "/opt/fenics-adaptive/demos/esl_cantilever.py", "--out", "/results/esl_cantilever"]
