#!/usr/bin/env bash
# Install everything `pasta` needs, idempotently:
#   1. system packages (as root, Debian/Ubuntu): libusb-1.0-0 (open3d imports need it), python3-venv,
#      chromium and fonts-liberation (the MLflow UI browser test);
#   2. the virtual environment .venv and `pip install -e ".[dev]"`.
# Set PASTA_SKIP_APT=1 to skip step 1. Step 2 is skipped when pyproject.toml is unchanged since the
# last successful install (stamp file in .venv).
set -euo pipefail
cd "$(dirname "$0")/.."

apt_packages=(libusb-1.0-0 python3-venv chromium fonts-liberation)
if [ "${PASTA_SKIP_APT:-0}" = "1" ]; then
    echo "setup: PASTA_SKIP_APT=1, skipping apt packages (${apt_packages[*]})"
elif [ "$(id -u)" -ne 0 ]; then
    echo "setup: not root, skipping apt; make sure these are installed: ${apt_packages[*]}"
elif ! command -v apt-get >/dev/null 2>&1; then
    echo "setup: no apt-get on this machine, skipping apt; make sure these are installed: ${apt_packages[*]}"
elif dpkg -s "${apt_packages[@]}" >/dev/null 2>&1; then
    echo "setup: apt packages already installed (${apt_packages[*]})"
else
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y "${apt_packages[@]}"
fi

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv"
    python3 -m venv .venv
fi

stamp=.venv/.pasta-install-stamp
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x .venv/bin/pasta ]; then
    echo "setup: .venv is up to date with pyproject.toml"
else
    .venv/bin/python -m pip install --upgrade pip
    # torch==2.13.0 is pinned in pyproject.toml: pip takes the CPU wheel from local disk (find-links);
    # an unpinned torch would pull the CUDA build.
    .venv/bin/python -m pip install -e ".[dev]"
    echo "$want" > "$stamp"
fi
