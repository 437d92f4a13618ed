#!/usr/bin/env bash
# Install (scripts/setup.sh), then lint and run the test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh
source scripts/env.sh
export PREFECT_HOME="${PREFECT_HOME:-$PWD/.prefect}"
export PASTA_HOME="${PASTA_HOME:-$PWD/.pasta_home}"

.venv/bin/ruff check pasta flows tests benchmarks
.venv/bin/python -m pytest -q "$@"
