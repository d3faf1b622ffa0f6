"""Scenes: the YAML format (:mod:`.yaml_io`), and canonical generated scenes (:mod:`.gallery`)."""

from .gallery import BENCHMARK_DT, add_cloth_grid, benchmark_cloth, cloth_grid_pairs
from .yaml_io import DEFAULT_STEPS, PlotSpec, Scene, SolverConfig, load_scene, parse_scene

__all__ = ["BENCHMARK_DT", "add_cloth_grid", "benchmark_cloth", "cloth_grid_pairs",
           "DEFAULT_STEPS", "PlotSpec", "Scene", "SolverConfig", "load_scene", "parse_scene"]
