# SPDX-License-Identifier: Apache-2.0
"""
The package's shape, read from its imports (every import statement, type-only ones too).

No import cycle anywhere in star_tracker; no private name (leading underscore) imported from
another module; no sub-package of centroid/ over MAX_MODULES modules; every numba kernel of
centroid/ in a *_kernel.py module (one naming rule: the compiled loops beside the idea they serve).
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "star_tracker"
MAX_MODULES = 15  # per centroid sub-package, __init__ not counted


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in PACKAGE.rglob("*.py")}


def imports(path: Path, known: dict[str, Path]) -> list[tuple[str, str]]:
    """Return (module imported, name taken from it or "") of every import statement of the file."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(alias.name, "") for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            for alias in node.names:
                child = f"{source}.{alias.name}"
                found.append((child, "") if child in known else (source, alias.name))
    return [(module, taken) for module, taken in found if module in known]


def import_graph() -> dict[str, set[str]]:
    known = modules()
    return {name: {module for module, _ in imports(path, known) if module != name} for name, path in known.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
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
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle_in_the_package():
    assert cycles(import_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]


def test_no_private_name_is_imported_from_another_module():
    known = modules()
    private = [f"{module_name(path)} takes {taken} from {module}" for path in known.values()
               for module, taken in imports(path, known) if taken.startswith("_") and taken != "__version__"]
    assert private == []


def test_centroid_sub_packages_stay_small_and_kernels_follow_one_naming_rule():
    centroid = PACKAGE / "centroid"
    for sub in [p for p in centroid.iterdir() if (p / "__init__.py").is_file()]:
        count = len([p for p in sub.glob("*.py") if p.name != "__init__.py"])
        assert count <= MAX_MODULES, f"centroid/{sub.name} holds {count} modules"
    compiled_elsewhere = [str(p.relative_to(PACKAGE)) for p in centroid.rglob("*.py")
                          if not p.name.endswith("_kernel.py") and "@njit" in p.read_text()]
    assert compiled_elsewhere == []
