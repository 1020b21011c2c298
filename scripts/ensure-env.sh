#!/usr/bin/env bash
# Creates or refreshes the project's virtual environment in .venv.
# The environment is rebuilt only when pyproject.toml changes (a stamp file records its hash).
# It prints one line while it installs; pip's output is kept in .venv/ensure-env.log and
# printed only when the installation fails.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
python_bin="${PYTHON:-python3}"
stamp="$venv/.pyproject.sha256"
want="$(sha256sum "$root/pyproject.toml" | cut -d' ' -f1)"
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    exit 0
fi
if ! "$python_bin" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
    echo "error: Python >= 3.11 is required (found $("$python_bin" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
    exit 2
fi
echo "setting up the environment in $venv (first run only; takes a minute)..." >&2
[ -x "$venv/bin/python" ] || "$python_bin" -m venv "$venv"
log="$venv/ensure-env.log"
if ! {
    "$venv/bin/python" -m pip install --upgrade pip &&
        "$venv/bin/python" -m pip install -e "$root[dev,cluster]"
} > "$log" 2>&1; then
    cat "$log" >&2
    echo "error: installing the environment failed; pip's output above is also in $log" >&2
    exit 1
fi
echo "$want" > "$stamp"
