"""Former import paths of the modules that moved into subpackages: ``import springsim.driver`` keeps working.

:data:`MOVED` maps each former module name to the module's name now; no file stands at the old paths.
:class:`MovedModuleFinder`, which ``springsim/__init__.py`` puts on :data:`sys.meta_path`, answers an import of a
former name with the module itself (``springsim.driver is springsim.run.driver``, so ``from springsim.driver import
simulate`` and objects pickled under the former name load) and a :class:`DeprecationWarning` naming the new path.
The module is then in :data:`sys.modules` under both names, so the warning comes once per process and name.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import os
import sys
import warnings

__all__ = ["MOVED", "MovedModuleFinder", "install"]

#: Former module name -> the module's name now.
MOVED: dict[str, str] = {
    "springsim.builder": "springsim.model.builder",
    "springsim.topology": "springsim.model.topology",
    "springsim.driver": "springsim.run.driver",
    "springsim.adaptive": "springsim.run.adaptive",
    "springsim.options": "springsim.run.options",
    "springsim.energy": "springsim.run.energy",
    "springsim.export": "springsim.io.export",
    "springsim.viz": "springsim.io.viz",
    "springsim.reference": "springsim.analysis.reference",
}

# Frames that an import passes through on its way to the loader: the import system's, importlib.import_module's,
# and springsim/__init__.py's (its __getattr__ imports a former module asked for as an attribute).
_PASS_THROUGH = (os.path.normcase(importlib.__file__), os.path.normcase(__file__),
                 os.path.normcase(os.path.join(os.path.dirname(__file__), "__init__.py")))


def _warn_importer(message: str) -> None:
    """Issue ``message`` as a :class:`DeprecationWarning` of the code doing the import (the first frame outside the
    import machinery), as ``warnings.warn`` would with the right ``stacklevel``: the default filters then show it
    when a script imports a former name, and ``-W error::DeprecationWarning`` makes it an error."""
    frame = sys._getframe(1)
    while frame.f_back is not None and (frame.f_code.co_filename.startswith("<frozen importlib")
                                        or os.path.normcase(frame.f_code.co_filename) in _PASS_THROUGH):
        frame = frame.f_back
    module_globals = frame.f_globals
    warnings.warn_explicit(message, DeprecationWarning, frame.f_code.co_filename, frame.f_lineno,
                           module=module_globals.get("__name__", "<string>"),
                           registry=module_globals.setdefault("__warningregistry__", {}))


class _AliasLoader(importlib.abc.Loader):
    """Loads a former name as the module at its new name, with a :class:`DeprecationWarning`."""

    def __init__(self, old: str, new: str):
        self.old, self.new = old, new
        self._spec = None

    def create_module(self, spec):
        module = importlib.import_module(self.new)
        _warn_importer(f"{self.old} is deprecated: the module moved to {self.new}; import it from there")
        self._spec = module.__spec__
        return module

    def exec_module(self, module):
        # The import system set __spec__ to the former name's spec; the module keeps its own.
        module.__spec__ = self._spec


class MovedModuleFinder(importlib.abc.MetaPathFinder):
    """The finder of the former names in :data:`MOVED` (any other name: None, for the next finder)."""

    @classmethod
    def find_spec(cls, fullname, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(fullname, new))


def install() -> None:
    """Put :class:`MovedModuleFinder` first on :data:`sys.meta_path` (once)."""
    if MovedModuleFinder not in sys.meta_path:
        sys.meta_path.insert(0, MovedModuleFinder)
