"""The model and its construction: the immutable :class:`~springsim.model.model.Model` and the
:class:`~springsim.model.model.State` (:mod:`.model`), the :class:`~springsim.model.builder.ModelBuilder`
(:mod:`.builder`) and cloth-grid topology (:mod:`.topology`).

The names of :mod:`springsim.model.model` are re-exported here (``from springsim.model import Model``).
"""

from .model import AXES, FINGERPRINT_V1, ClothGrid, Model, State
from .model import _rebuild  # noqa: F401  (models pickled before the module moved name springsim.model._rebuild)

__all__ = ["Model", "State", "ClothGrid", "AXES", "FINGERPRINT_V1"]
