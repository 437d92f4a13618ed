#!/usr/bin/env bash
# Install (scripts/setup.sh), then run one task's whole pipeline: `bash scripts/run.sh --task CRS --profile small`.
# Arguments go to `pasta run`; with none, CutRearrange at the smoke profile (the README's main job).
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh
source scripts/env.sh

if [ "$#" -eq 0 ]; then
  set -- --task CutRearrange --profile smoke
fi
exec .venv/bin/pasta run "$@"
