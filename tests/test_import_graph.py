"""The project's modules import each other without cycles, and the packages keep their layers.

The graph is read from the source with ``ast`` (every ``import`` and ``from ... import``
statement, at module level or inside functions, relative imports resolved), not by
importing anything.  A node is a module (``identify.fits.output_error``); a package's
``__init__.py`` is the package's own node (``identify``).  ``from pkg import name``
points at ``pkg.name`` when that is a module, else at ``pkg``.

Layers: ``identify -> motorsim <- hardware``; ``scenarios -> identify, motorsim``; the app,
``motorid``, may use everything and nothing imports it.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("motorsim", "identify", "scenarios", "hardware", "motorid")
#: Project packages each package must not import.
FORBIDDEN = {
    "motorsim": {"identify", "scenarios", "hardware", "motorid"},
    "identify": {"scenarios", "hardware", "motorid"},
    "hardware": {"identify", "scenarios", "motorid"},
    "scenarios": {"hardware", "motorid"},
    "motorid": set(),
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _sources() -> dict[str, Path]:
    """Every project module by dotted name."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if "build" not in path.relative_to(ROOT).parts:
                found[_module_name(path)] = path
    return found


def _imported_names(tree: ast.Module, module: str, is_package: bool) -> list[tuple[str, int]]:
    """Dotted names a module imports (``(name, line)``), relative imports made absolute.

    ``from pkg import name`` gives ``pkg.name``; :func:`_resolve` falls back to ``pkg``
    when ``name`` is not a module.
    """
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            out += [(f"{stem}.{alias.name}", node.lineno) for alias in node.names]
    return out


def _resolve(name: str, modules: set[str]) -> str | None:
    """The longest project module that ``name`` starts with (None outside the project)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        candidate = ".".join(parts[:n])
        if candidate in modules:
            return candidate
    return None


def build_graph() -> dict[str, dict[str, int]]:
    """``graph[a][b] = line``: module ``a`` imports project module ``b`` at that line."""
    sources = _sources()
    modules = set(sources)
    graph: dict[str, dict[str, int]] = {m: {} for m in modules}
    for module, path in sources.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for name, line in _imported_names(tree, module, path.name == "__init__.py"):
            target = _resolve(name, modules)
            if target is not None and target != module:
                graph[module].setdefault(target, line)
    return graph


def find_cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(components)


def _describe(component: list[str], graph: dict[str, dict[str, int]]) -> str:
    members = set(component)
    edges = [f"{a} -> {b} (line {graph[a][b]})" for a in component for b in sorted(graph[a]) if b in members]
    return "cycle between " + ", ".join(component) + ":\n    " + "\n    ".join(edges)


GRAPH = build_graph()


def test_the_graph_sees_the_project():
    assert {"identify.fits.output_error", "identify.checks.validation", "motorsim.plant", "motorid.cli",
            "hardware.serial_rig"} <= set(GRAPH)
    assert "identify.checks.validation" in GRAPH["identify.fits.output_error"]


def test_find_cycles_names_a_cycle():
    assert find_cycles({"a": {"b": 1}, "b": {"c": 2}, "c": {"a": 3}, "d": {"a": 4}}) == [["a", "b", "c"]]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_cycle(package):
    cycles = [c for c in find_cycles(GRAPH) if any(m.split(".")[0] == package for m in c)]
    assert not cycles, "\n".join(_describe(c, GRAPH) for c in cycles)


@pytest.mark.parametrize("package", PACKAGES)
def test_layers(package):
    offenders = [f"{a} imports {b} (line {line})" for a, targets in sorted(GRAPH.items())
                 if a.split(".")[0] == package
                 for b, line in sorted(targets.items()) if b.split(".")[0] in FORBIDDEN[package]]
    assert not offenders, f"{package} must not import {sorted(FORBIDDEN[package])}:\n" + "\n".join(offenders)


def test_nothing_outside_the_app_imports_it():
    offenders = [f"{a} imports {b} (line {line})" for a, targets in sorted(GRAPH.items())
                 if a.split(".")[0] != "motorid"
                 for b, line in sorted(targets.items()) if b.split(".")[0] == "motorid"]
    assert not offenders, "only motorid may import motorid:\n" + "\n".join(offenders)


#: What a package may import of another: ``PUBLIC[importer][imported]`` is ``"package"`` when only the
#: names the imported package exports (its ``__all__``) count as public, ``"module"`` when a
#: module's own ``__all__`` counts too (the module and the name not underscore-prefixed).  identify's
#: public names are its package index (its modules are topic modules behind it); motorsim's modules
#: are public one by one (``motorsim.checks``, ``motorsim.batch``, ...).
PUBLIC = {"scenarios": {"identify": "package", "motorsim": "module"}}


def _public_names(module: str) -> set[str]:
    import importlib
    return set(getattr(importlib.import_module(module), "__all__", ()))


def private_imports(tree: ast.Module, rules: dict[str, str]) -> list[str]:
    """The imports in ``tree`` of names that ``rules`` (imported package -> "package" or "module")
    does not count as public, each as ``"module.name (line N)"``."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            pairs = [(alias.name, None) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            pairs = [(node.module, alias.name) for alias in node.names]
        else:
            continue
        for module, name in pairs:
            package = module.split(".")[0]
            if package not in rules:
                continue
            if name is None:        # ``import identify.x``: every name of the module within reach
                if module != package:
                    found.append(f"{module} (line {node.lineno})")
                continue
            public = name in _public_names(package) or (
                rules[package] == "module" and not any(p.startswith("_") for p in module.split("."))
                and name in _public_names(module))
            if name.startswith("_") or not public:
                found.append(f"{module}.{name} (line {node.lineno})")
    return found


def test_private_imports_are_found():
    source = ("from identify import fit\nfrom identify.fits.sensitivity import phi_functions\n"
              "def f():\n    from motorsim.plant import Motor, _private\n    import identify.data\n"
              "from motorsim.checks import ParameterError\n")
    found = private_imports(ast.parse(source), PUBLIC["scenarios"])
    assert found == ["identify.fits.sensitivity.phi_functions (line 2)", "motorsim.plant._private (line 4)",
                     "identify.data (line 5)"]


@pytest.mark.parametrize("importer", sorted(PUBLIC))
def test_imports_across_packages_are_public(importer):
    offenders = []
    for module, path in sorted(_sources().items()):
        if module.split(".")[0] == importer:
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            offenders += [f"{module} imports {x}" for x in private_imports(tree, PUBLIC[importer])]
    assert not offenders, f"{importer} may import only public names:\n" + "\n".join(offenders)
