#!/usr/bin/env bash
# Rewrites requirements/lock.txt from a throw-away virtualenv built from the direct pins of
# requirements/ alone: every distribution they bring, at the version pip resolves today. Run it
# after changing a pin, then run the tests (tests/test_packaging.py checks the lock).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
python=${PYTHON:-$root/.venv/bin/python}
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
"$python" -m venv "$scratch/venv"
"$scratch/venv/bin/python" -m pip install --quiet --upgrade pip
"$scratch/venv/bin/python" -m pip install --quiet -r "$root/requirements/native.txt" \
    -r "$root/requirements/docs.txt"
{
    sed -n '/^#/p' "$root/requirements/lock.txt"
    "$scratch/venv/bin/python" -m pip freeze --exclude-editable | grep -v '^#' | sort -f
} > "$scratch/lock.txt"
mv "$scratch/lock.txt" "$root/requirements/lock.txt"
echo "lock: wrote requirements/lock.txt ($(grep -vc '^#' "$root/requirements/lock.txt") pins)"
