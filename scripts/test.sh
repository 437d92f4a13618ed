#!/usr/bin/env bash
# Install (scripts/setup.sh), then lint and run the test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh

# Taichi's offline kernel cache: keep it outside the checkout so it stays warm across runs and clones.
export TI_OFFLINE_CACHE_FILE_PATH="${TI_OFFLINE_CACHE_FILE_PATH:-$HOME/.cache/pasta/ticache}"
export PREFECT_SERVER_ANALYTICS_ENABLED="${PREFECT_SERVER_ANALYTICS_ENABLED:-false}"
export PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS="${PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS:-90}"
export PREFECT_HOME="${PREFECT_HOME:-$PWD/.prefect}"
export PASTA_HOME="${PASTA_HOME:-$PWD/.pasta_home}"
mkdir -p "$TI_OFFLINE_CACHE_FILE_PATH"

.venv/bin/ruff check pasta flows tests benchmarks
.venv/bin/python -m pytest -q "$@"
