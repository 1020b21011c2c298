# One image for every process of the networked swarm: router, world, robots, dashboard.
#
#   docker compose build                  (or: docker build -t swarm-cps:local .)
#
# BASE_IMAGE must provide python3 3.11 with the venv module: python:3.11-slim (the default), or
# a Debian bookworm rootfs with python3 and python3-venv, which scripts/compose-smoke.sh makes
# with debootstrap and imports as local/debian-py:bookworm where no registry is reachable.
#
# Python packages come from PyPI, or, when WHEELS_URL is set, only from the wheels listed at
# that URL (pip --no-index --find-links): scripts/compose-smoke.sh downloads them on the host,
# pinned to the versions in .venv, and serves them on 127.0.0.1 to a build that runs on the
# host's network (docker-compose.ci.yml). Either way the wheels never enter the image.
#
# The project is installed in editable mode at /app on purpose: robot_firmware/net/session.py
# reads configs/zenoh/*.json5 from beside the source tree (wait for the router, reconnect, short
# lease), so the source stays at /app with configs/ next to it (compose mounts ./configs there).
# No compilers, no dev tools, no test suites. Only the modules the project imports are
# byte-compiled (at build time), which keeps the image smaller and container starts fast.
# The compiled control and body kernels (numba) are compiled at build time too, into
# NUMBA_CACHE_DIR=/opt/numba-cache (readable and writable by any user), so that no container
# pays the compile time (about 13 s) at its start.  The robots' kernels compiled ahead of time
# (robot_firmware/control/aot.py: a robot process with SWARM_KERNELS=aot never imports numba)
# go to SWARM_AOT_DIR=/opt/aot-kernels; that build needs a C compiler, so where the base image
# has none it is skipped with a note and robots run numba's JIT from the cache.  The robots'
# register model and drivers run from source here: their mypyc build (robot_firmware/native.py)
# needs mypy, a development tool the image leaves out.

ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ARG WHEELS_URL=
ENV PATH=/opt/venv/bin:$PATH \
    VIRTUAL_ENV=/opt/venv \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_ROOT_USER_ACTION=ignore \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib \
    NUMBA_CACHE_DIR=/opt/numba-cache \
    SWARM_AOT_DIR=/opt/aot-kernels

# The runtime dependencies of pyproject.toml (and setuptools, the build backend of the editable
# install below), in their own layer so that it survives edits of the source.
COPY pyproject.toml /tmp/pyproject.toml
RUN set -eu; \
    if [ -n "$WHEELS_URL" ]; then \
        echo "installing from the wheels at $WHEELS_URL only"; \
        set -- --no-index --find-links "$WHEELS_URL"; \
    else \
        set --; \
        if [ -f /etc/ssl/certs/ca-certificates.crt ]; then \
            export PIP_CERT=/etc/ssl/certs/ca-certificates.crt; \
        fi; \
    fi; \
    python3 -m venv /opt/venv; \
    python -c 'import sys, tomllib; \
print("\n".join(tomllib.load(open(sys.argv[1], "rb"))["project"]["dependencies"]))' \
        /tmp/pyproject.toml > /tmp/requirements.txt; \
    pip install "$@" --no-compile --only-binary=:all: -r /tmp/requirements.txt \
        "setuptools>=77" wheel; \
    find /opt/venv/lib/python3*/site-packages -depth -type d -name tests -exec rm -rf {} +; \
    rm -rf /tmp/pyproject.toml /tmp/requirements.txt

# The source: the packages that pyproject.toml names, the scenarios and the Zenoh configs.
COPY pyproject.toml README.md /app/
COPY robot_firmware /app/robot_firmware
COPY swarm_config /app/swarm_config
COPY world /app/world
COPY services /app/services
COPY configs /app/configs
WORKDIR /app
RUN set -eu; \
    pip install --no-index --no-deps --no-build-isolation -e /app; \
    rm -rf /app/build /app/*.egg-info; \
    swarm --help > /dev/null; \
    python -c 'import importlib, pkgutil; \
names = [m.name for p in ("robot_firmware", "swarm_config", "world", "services") \
         for m in pkgutil.walk_packages(importlib.import_module(p).__path__, p + ".") \
         if not m.name.endswith("__main__")]; \
[importlib.import_module(n) for n in names]; \
print(f"imported {len(names)} project modules: their byte code is in the image")'; \
    python -c 'from pathlib import Path; \
from services.sim.batch import run_batch; \
from swarm_config.scenario import load_scenario; \
scenario = load_scenario(Path("configs/scenarios/paper.yaml")); \
[run_batch(scenario, batch_size=b, duration_s=0.1) for b in (1, 30)]; \
from world.engine import WorldEngine; WorldEngine(scenario).compile_kernels(); \
print("compiled the control and body kernels into the numba cache")'; \
    if command -v cc > /dev/null; then \
        SWARM_KERNELS=jit python -m robot_firmware.control.aot; \
    else \
        echo "no C compiler: robots will run the control kernels through numba's JIT"; \
    fi; \
    chmod -R a+rwX /opt/numba-cache; \
    mkdir -p /runs

# 7447: Zenoh router; 9090: Rerun web viewer; 9876: Rerun gRPC (dashboard).
EXPOSE 7447 9090 9876
STOPSIGNAL SIGTERM
CMD ["swarm", "--help"]
