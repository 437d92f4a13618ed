"""Point-cloud geometry: distances (Chamfer, EMD, Sinkhorn), DBSCAN entities, resampling, matching.

Depends on numpy, scipy, scikit-learn and torch only; nothing here knows the simulator or the models.
"""

from pasta.geometry.distances import (
    as_generator,
    chamfer_distance,
    earth_movers_distance,
    is_success,
    normalised_performance,
    sinkhorn_emd,
)
from pasta.geometry.entities import EntityMatch, label_entities, match_entities, resample, split_entities

__all__ = [
    "EntityMatch",
    "as_generator",
    "chamfer_distance",
    "earth_movers_distance",
    "is_success",
    "label_entities",
    "match_entities",
    "normalised_performance",
    "resample",
    "sinkhorn_emd",
    "split_entities",
]
