"""Global assembly of the implicit system: symbolic pattern once, numeric scatter every step."""

from .assemble import SystemAssembler, SystemMatrix
from .dense import dense_system, dense_system_free
from .fixed import condense, enforce_identity, expand, free_dofs
from .pattern import BlockPattern

__all__ = ["BlockPattern", "SystemAssembler", "SystemMatrix", "dense_system", "dense_system_free",
           "condense", "enforce_identity", "expand", "free_dofs"]
