# Each target is a one-liner; read the script it calls for details.
.PHONY: setup test demo bench lint

setup:
	bash scripts/setup.sh

test:
	bash scripts/test.sh

demo: setup
	.venv/bin/pasta sim-demo --task CutRearrange --profile small

bench: setup
	.venv/bin/python benchmarks/sim.py --quick

lint:
	.venv/bin/ruff check pasta flows tests benchmarks
