# Each target is a one-liner; read the script it calls for details.
.PHONY: setup run test sim-demo bench lint ui report

setup:
	bash scripts/setup.sh

# The main job: CutRearrange's whole pipeline (data, training, evaluation, report) at the smoke profile.
# Its report goes to build/reports/ (git-ignored), never to the published reports/.
run:
	bash scripts/run.sh --task CutRearrange --profile smoke

test:
	bash scripts/test.sh

sim-demo: setup
	.venv/bin/pasta sim-demo --task CutRearrange --profile small

bench: setup
	.venv/bin/python benchmarks/sim.py --quick
	.venv/bin/python benchmarks/plan.py --quick
	.venv/bin/python benchmarks/train.py --quick

lint:
	.venv/bin/ruff check pasta flows tests benchmarks

# The MLflow UI on this project's store (or $MLFLOW_TRACKING_URI): http://127.0.0.1:5000
ui: setup
	.venv/bin/mlflow ui --backend-store-uri $${MLFLOW_TRACKING_URI:-sqlite:///$(CURDIR)/mlflow.db} --port 5000

# Rebuild every report from MLflow into build/reports/ (git-ignored); `.venv/bin/pasta report --publish`
# writes the published reports/ instead.
report: setup
	.venv/bin/pasta report
