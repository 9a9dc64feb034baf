"""How much of the structure of space a motor representation captured (docs/MODEL.md §4)."""

from smspace.metrics.spatial import SpatialScores, affine_projection, spatial_scores

__all__ = ["SpatialScores", "affine_projection", "spatial_scores"]
