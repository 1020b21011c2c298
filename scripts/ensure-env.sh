#!/usr/bin/env bash
# Creates or refreshes the project's virtual environment in .venv.
# The environment is rebuilt only when pyproject.toml changes (a stamp file records its hash).
# It prints one line while it installs; pip's output is kept in .venv/ensure-env.log and
# printed only when the installation fails.
# Then the robot processes' control kernels are compiled ahead of time (numba.pycc, about a
# minute) when no module for the current control sources is there (robot_firmware/control/aot.py);
# if that fails the robots run numba's JIT instead, so it only warns.  Likewise their register
# model and drivers are compiled with mypyc (robot_firmware/native_build.py, about a minute);
# if that fails the robots run them from source.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
python_bin="${PYTHON:-python3}"
stamp="$venv/.pyproject.sha256"
want="$(sha256sum "$root/pyproject.toml" | cut -d' ' -f1)"
ensure_aot_kernels() {
    if SWARM_KERNELS=jit "$venv/bin/python" -m robot_firmware.control.aot --check > /dev/null; then
        return 0
    fi
    echo "compiling the robots' control kernels ahead of time (after a kernel edit; about a minute)..." >&2
    if ! SWARM_KERNELS=jit "$venv/bin/python" -m robot_firmware.control.aot > "$venv/aot-kernels.log" 2>&1; then
        echo "warning: the ahead-of-time build failed (robots will use numba's JIT); see $venv/aot-kernels.log" >&2
    fi
}
ensure_native_build() {
    if SWARM_NATIVE=python "$venv/bin/python" -m robot_firmware.native_build --check > /dev/null; then
        return 0
    fi
    echo "compiling the robots' register model and drivers with mypyc (after an edit; about a minute)..." >&2
    if ! SWARM_NATIVE=python "$venv/bin/python" -m robot_firmware.native_build > "$venv/native-build.log" 2>&1; then
        echo "warning: the mypyc build failed (robots will run their register model from source); see $venv/native-build.log" >&2
    fi
}
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    ensure_aot_kernels
    ensure_native_build
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
ensure_aot_kernels
ensure_native_build
