#!/usr/bin/env bash
# Installs Debian's Chromium for the dashboard's browser test when it is missing and this user
# may install packages (root with apt-get). Exits non-zero when no browser can be had.
set -uo pipefail
if command -v chromium >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" != "0" ] || ! command -v apt-get >/dev/null 2>&1; then
    exit 1
fi
echo "installing Debian's chromium for the browser test (once)..." >&2
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null 2>&1 || true
apt-get install -y -qq chromium >/dev/null 2>&1 || exit 1
command -v chromium >/dev/null 2>&1
