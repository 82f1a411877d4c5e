#!/usr/bin/env bash
# Create .venv with a Python >= 3.12 and install the project (editable) with its dev extras.
# Idempotent: re-running after pyproject.toml changes reinstalls; otherwise it is a no-op.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=.venv
STAMP="$VENV/.installed"

is_new_enough() {
    "$1" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 12) else 1)' >/dev/null 2>&1
}

find_python() {
    local candidate
    # An explicit choice wins; then the usual names on PATH; then pyenv's folder, which works even
    # when the pyenv shims are not on PATH or need PYENV_VERSION to resolve.
    for candidate in "${PYTHON:-}" python3.13 python3.12 python3; do
        [ -n "$candidate" ] || continue
        if command -v "$candidate" >/dev/null 2>&1 && is_new_enough "$candidate"; then
            command -v "$candidate"
            return 0
        fi
    done
    for candidate in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.1[2-9]*/bin/python3; do
        if [ -x "$candidate" ] && is_new_enough "$candidate"; then
            echo "$candidate"
            return 0
        fi
    done
    return 1
}

# The tests of the human experts' windows draw on a virtual X display (tests/xvfb.py) and are
# skipped without Xvfb: install it where we can (root with apt-get), never failing the bootstrap.
install_xvfb() {
    [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 || return 1
    export DEBIAN_FRONTEND=noninteractive
    # A fresh container has no package lists: fetch them only when the plain install fails.
    apt-get install -y -qq --no-install-recommends xvfb >/dev/null 2>&1 \
        || { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq --no-install-recommends xvfb >/dev/null 2>&1; }
}
if ! command -v Xvfb >/dev/null 2>&1; then
    if install_xvfb; then
        echo "bootstrap: installed Xvfb (for the expert-window tests)" >&2
    else
        echo "bootstrap: Xvfb missing and not installable here (needs root and apt-get); the expert-window tests will be skipped" >&2
    fi
fi

if [ -f "$STAMP" ] && [ "$STAMP" -nt pyproject.toml ] && is_new_enough "$VENV/bin/python"; then
    exit 0
fi

if ! PY=$(find_python); then
    echo "error: Python >= 3.12 is required (lerobot needs it) and none was found." >&2
    echo "Install one (e.g. 'pyenv install 3.12' or your OS package python3.12), or set PYTHON=/path/to/python3.12." >&2
    exit 1
fi

if [ -x "$VENV/bin/python" ] && ! is_new_enough "$VENV/bin/python"; then
    echo "bootstrap: $VENV has an old Python; recreating it" >&2
    rm -rf "$VENV"
fi
if [ ! -x "$VENV/bin/python" ]; then
    echo "bootstrap: creating $VENV with $PY ($("$PY" --version 2>&1))" >&2
    "$PY" -m venv "$VENV"
fi
echo "bootstrap: installing the project and its dependencies into $VENV (first time: a few minutes)" >&2
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet -e ".[dev]"
touch "$STAMP"
echo "bootstrap: ready" >&2
