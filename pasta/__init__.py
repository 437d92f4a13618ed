"""pasta: a CPU-first re-implementation of PASTA (CoRL 2022).

Planning with Spatial-Temporal Abstraction from point clouds for deformable dough manipulation:
a Taichi MLS-MPM simulator, entity point-cloud models in torch, a latent set planner, and
Prefect flows that track every run in MLflow.
"""

__version__ = "0.1.0"
