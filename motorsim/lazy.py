"""Names a module loads when first asked for: one mechanism for every lazy import of the project.

Three helpers:

- :func:`load` imports ``"module:name"`` now, for registries that name what they hold as
  text so that registering costs no import (estimators, port schemes);
- :func:`lazy_attributes` gives a module the PEP 562 ``__getattr__`` and ``__dir__`` that
  resolve its names on first use: names defined in a submodule, loaded and cached
  (``exports``); names that moved elsewhere, which warn with a ``DeprecationWarning``
  for one release (``moved``);
- :func:`moved_modules` keeps a package's modules that moved into a subpackage importable by their earlier
  names (the same module objects).

The app's ``motorid.__version__``, a value read when asked rather than an import, keeps its
own ``__getattr__``: importing this module runs ``motorsim/__init__`` (numpy, the
simulator), which ``motorid --help`` does not load.

For example:

>>> load("math:tau") > 6.28
True
>>> load(".checks:check_int", "motorsim").__name__
'check_int'
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from typing import Any, Callable, Mapping

from .checks import ParameterError

__all__ = ["load", "lazy_attributes", "moved_modules"]


def load(target: str, package: str | None = None) -> Any:
    """The object ``target`` names, ``"module:name"``, imported now.

    Parameters
    ----------
    target : str
        ``"module:name"``; a module starting with ``.`` is relative to ``package``.
    package : str, optional
        The package a relative module is resolved against.
    """
    module, sep, name = target.partition(":")
    if not (module and sep and name):
        raise ParameterError(f"target must be 'module:name', got {target!r}")
    return getattr(importlib.import_module(module, package), name)


def lazy_attributes(module_name: str, *, exports: Mapping[str, str] | None = None,
                    moved: Mapping[str, str] | None = None,
                    hint: str = "") -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for the module ``module_name`` (PEP 562).

    Parameters
    ----------
    module_name : str
        The module's ``__name__``.
    exports : mapping of str to str, optional
        Name -> the module defining it (relative to ``module_name`` when it starts with ``.``,
        which then must be a package); loaded on first use and kept in the module's globals.
    moved : mapping of str to str, optional
        Name -> the module it moved to; each use warns (``DeprecationWarning``) and returns it.
    hint : str, optional
        Words added after the new place in the warning of a moved name (``{name}`` is replaced
        by the name).

    Examples
    --------
    >>> getattr_, dir_ = lazy_attributes("motorsim", moved={"check_int": "motorsim.checks"})
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     getattr_("check_int").__name__
    'check_int'
    >>> print(caught[0].message)
    motorsim.check_int moved to motorsim.checks.check_int; the old name goes in the next release
    """
    exports, moved = dict(exports or {}), dict(moved or {})

    def __getattr__(name: str) -> Any:
        if name in exports:
            value = getattr(importlib.import_module(exports[name], module_name), name)
            setattr(sys.modules[module_name], name, value)
            return value
        if name in moved:
            extra = hint.format(name=name)
            warnings.warn(f"{module_name}.{name} moved to {moved[name]}.{name}{extra}; the old name goes in the "
                          "next release", DeprecationWarning, stacklevel=2)
            return getattr(importlib.import_module(moved[name]), name)
        raise AttributeError(f"module {module_name!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[module_name]), *exports})

    return __getattr__, __dir__


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports of a package's modules by the names they had before they moved into a subpackage."""

    def __init__(self, package: str, moved: Mapping[str, str]) -> None:
        self.package, self.moved = package, dict(moved)

    def _earlier(self, fullname: str) -> str | None:
        """``fullname``'s earlier name relative to the package (``selection``, ``default.comparison``), if it moved."""
        prefix = self.package + "."
        earlier = fullname[len(prefix):] if fullname.startswith(prefix) else None
        return earlier if earlier in self.moved else None

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if self._earlier(fullname) is None:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None

    def exec_module(self, module: Any) -> None:
        # the import system hands back what sys.modules holds under the name once this returns: the module itself
        earlier = self._earlier(module.__name__)
        assert earlier is not None
        sys.modules[module.__name__] = importlib.import_module(f"{self.package}.{self.moved[earlier]}")


def moved_modules(package: str, moved: Mapping[str, str]) -> None:
    """Keep the modules of ``package`` that moved into a subpackage importable by their earlier names.

    ``import package.selection`` (or ``from package.selection import x``) then gives the module itself,
    ``package.default.selection``: the same object, so a name patched through either path is patched for both;
    nothing is imported until asked for, and nothing warns.

    Parameters
    ----------
    package : str
        The package's name (``"identify"``).
    moved : mapping of str to str
        An earlier module name -> where the module is now, both relative to ``package``
        (``{"selection": "default.selection"}``; an earlier name may be in a subpackage, ``"default.comparison"``).
    """
    for finder in sys.meta_path:
        if isinstance(finder, _MovedModules) and finder.package == package:
            finder.moved.update(moved)
            return
    sys.meta_path.append(_MovedModules(package, moved))
