"""Prefect flows: orchestration, caching, MLflow runs and artifacts on top of `pasta`."""
