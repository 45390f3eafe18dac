#!/usr/bin/env bash
# Creates (or refreshes) the virtualenv .venv at the repository root with DOLFINx 0.11 (real PETSc,
# mpich), numba, gmsh, matplotlib, pytest and ruff at the versions pinned in requirements/, the
# documentation tools of requirements/docs.txt (Sphinx, MyST-NB), everything they bring at the
# versions of requirements/lock.txt, and installs fenics-adaptive into it in editable mode.
# The system libraries the gmsh wheel links against are checked (and installed with apt-get
# when missing and the script runs as root; otherwise it names them and stops). Idempotent: when nothing it depends on has changed since the last
# successful install, it does nothing and exits in well under a second.
# It also makes Debian's Chromium available for the documentation's browser test: installed with
# apt-get when missing and the script runs as root; otherwise it says so and that test skips.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv="$root/.venv"
stamp="$venv/.fenics-adaptive-install"

fingerprint() {
    cat "$root/requirements/native.txt" "$root/requirements/common.txt" \
        "$root/requirements/gmsh.txt" "$root/requirements/docs.txt" \
        "$root/requirements/lock.txt" "$root/pyproject.toml" \
        | sha256sum | cut -d' ' -f1
}

# Chromium (the headless browser of tests/test_docs_site.py) is a system package.
if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then
    if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
        echo "install: installing Debian's chromium (headless browser for the docs test)"
        if ! { DEBIAN_FRONTEND=noninteractive apt-get update -qq \
                && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; } >/dev/null; then
            echo "install: apt-get could not install chromium; the browser test will skip" >&2
        fi
    else
        echo "install: chromium is missing and this is not root with apt-get: install it" \
             "(apt-get install chromium) or the docs browser test skips" >&2
    fi
fi

# The gmsh wheel links against these; a bare server lacks them, and gmsh then fails on import.
gmsh_libraries=(libGLU.so.1 libXcursor.so.1 libXft.so.2 libXinerama.so.1 libXrender.so.1)
gmsh_packages="libglu1-mesa libxcursor1 libxft2 libxinerama1 libxrender1"
ldconfig=$(command -v ldconfig || echo /sbin/ldconfig)
if [[ -x "$ldconfig" ]]; then
    known=$("$ldconfig" -p 2>/dev/null || true)
    missing=()
    for library in "${gmsh_libraries[@]}"; do
        grep -q "$library" <<<"$known" || missing+=("$library")
    done
    if ((${#missing[@]})); then
        if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
            echo "install: installing the libraries the gmsh wheel needs (${missing[*]})"
            # shellcheck disable=SC2086
            { DEBIAN_FRONTEND=noninteractive apt-get update -qq \
                && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $gmsh_packages; } >/dev/null \
                || { echo "install: apt-get could not install $gmsh_packages" >&2; exit 1; }
        else
            echo "install: the gmsh wheel needs ${missing[*]}, which this system lacks:" \
                 "install them (Debian/Ubuntu: apt-get install $gmsh_packages) and run again" >&2
            exit 1
        fi
    fi
fi

if [[ -x "$venv/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$(fingerprint)" ]]; then
    exit 0
fi

# DOLFINx's binary wheel exists for CPython >= 3.12 only.
suitable() {
    "$1" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 12) else 1)' >/dev/null 2>&1
}

find_python() {
    local candidate
    for candidate in python3.14 python3.13 python3.12 python3; do
        if command -v "$candidate" >/dev/null 2>&1 && suitable "$candidate"; then
            command -v "$candidate"
            return 0
        fi
    done
    # pyenv keeps interpreters that are installed but not selected in its versions folder.
    for candidate in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.1[2-9]*/bin/python3; do
        if [[ -x "$candidate" ]] && suitable "$candidate"; then
            echo "$candidate"
            return 0
        fi
    done
    return 1
}

if [[ ! -x "$venv/bin/python" ]] || ! suitable "$venv/bin/python"; then
    if ! python=$(find_python); then
        echo "install: no Python >= 3.12 found (tried python3.14 .. python3.12 and python3 on PATH," \
             "and ${PYENV_ROOT:-$HOME/.pyenv}/versions). DOLFINx's wheel needs CPython >= 3.12:" \
             "install one and run this script again." >&2
        exit 1
    fi
    echo "install: creating $venv with $python ($("$python" --version 2>&1))"
    rm -rf "$venv"
    "$python" -m venv "$venv"
fi

echo "install: installing pinned dependencies into $venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
lock=(-c "$root/requirements/lock.txt")
"$venv/bin/python" -m pip install --quiet "${lock[@]}" -r "$root/requirements/native.txt"
"$venv/bin/python" -m pip install --quiet "${lock[@]}" -r "$root/requirements/docs.txt"
"$venv/bin/python" -m pip install --quiet --no-deps -e "$root"
# Fail here, not in the first test, if the stack does not import.
"$venv/bin/python" -c 'from mpi4py import MPI; import dolfinx, numba, matplotlib' \
    || { echo "install: the installed stack does not import; see the error above." >&2; exit 1; }
"$venv/bin/python" -c 'import gmsh' \
    || { echo "install: gmsh does not import; its wheel needs $gmsh_packages" \
              "(Debian/Ubuntu package names)" >&2; exit 1; }
fingerprint > "$stamp"
echo "install: done ($("$venv/bin/python" -c 'from mpi4py import MPI; import dolfinx; print("DOLFINx", dolfinx.__version__)'))"
