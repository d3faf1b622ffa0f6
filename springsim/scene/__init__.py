"""Scenes: the YAML format (:mod:`.yaml_io`), and canonical generated scenes (:mod:`.gallery`)."""

from ..run.options import DEFAULT_STEPS, SolverConfig
from .gallery import BENCHMARK_DT, benchmark_cloth
from .yaml_io import PlotSpec, Scene, load_scene, parse_scene

__all__ = ["BENCHMARK_DT", "benchmark_cloth", "DEFAULT_STEPS", "PlotSpec", "Scene", "SolverConfig", "load_scene",
           "parse_scene"]
