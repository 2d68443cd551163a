#!/usr/bin/env bash
# The Python venv of a test that checks our files with independent readers (Python `rosbags`,
# `mcap`, ...): makes VENV once (`python3 -m venv`), installs PKG... with pip unless `import
# IMPORTS` already works in it (needs PyPI then), and prints its interpreter's path.
# Usage: scripts/pyenv.sh VENV IMPORTS PKG...   e.g. scripts/pyenv.sh target/pyenv-rosbags rosbags rosbags==0.11.9
set -euo pipefail
venv=$1 imports=$2
shift 2
py="$venv/bin/python"
# Tests run in parallel: one of them makes the venv, the others wait for it.
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9
[ -x "$py" ] || python3 -m venv "$venv" >&2 || { echo "pyenv: python3 -m venv $venv failed (is python3-venv installed?)" >&2; exit 1; }
"$py" -c "import $imports" 2>/dev/null \
  || "$py" -m pip install --quiet --disable-pip-version-check "$@" >&2 \
  || { echo "pyenv: pip install $* failed (needs PyPI)" >&2; exit 1; }
echo "$py"
