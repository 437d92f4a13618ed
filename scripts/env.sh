# Environment shared by scripts/test.sh and scripts/run.sh (sourced, not run).
# Taichi's offline kernel cache lives outside the checkout so it stays warm across runs and clones.
export TI_OFFLINE_CACHE_FILE_PATH="${TI_OFFLINE_CACHE_FILE_PATH:-$HOME/.cache/pasta/ticache}"
export PREFECT_SERVER_ANALYTICS_ENABLED="${PREFECT_SERVER_ANALYTICS_ENABLED:-false}"
export PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS="${PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS:-90}"
mkdir -p "$TI_OFFLINE_CACHE_FILE_PATH"
