"""Scenes: the YAML format, and canonical generated scenes (:mod:`.gallery`)."""

from .gallery import BENCHMARK_DT, add_cloth_grid, benchmark_cloth, cloth_grid_pairs

__all__ = ["BENCHMARK_DT", "add_cloth_grid", "benchmark_cloth", "cloth_grid_pairs"]
