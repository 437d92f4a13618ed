"""Training loops (VAE; policy, feasibility and cost heads) and the ``TrainedModels`` bundle they produce.

Loops report metrics through a callback and never talk to MLflow themselves.
"""

from pasta.train.bundle import (
    DEFAULT_FILTER_EPSILON,
    TrainedModels,
    action_dim_of,
    load_trained,
    save_trained,
    untrained,
)

__all__ = ["DEFAULT_FILTER_EPSILON", "TrainedModels", "action_dim_of", "load_trained", "save_trained", "untrained"]
