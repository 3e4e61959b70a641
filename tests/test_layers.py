"""The package's imports go one way: no cycle, and no module imports from a layer above
its own.

The layers, lowest first (a module may import from its own subpackage and from lower
layers only; subpackages of one layer do not import each other):

0. ``core``: pure math on arrays;
1. ``models`` (motion and observation models) and ``runtime`` (compiler options,
   executables, cache, chunked scans, keys);
2. ``datasets``: host-side loaders and simulators;
3. ``metrics``: trajectory and map error (they read reference files through the loaders);
4. ``base``: the filter protocol;
5. ``feature`` and ``grid``: the filters and their whole-run entry points;
6. ``filters`` (the factories), ``calibrate`` and ``localization`` (Monte Carlo
   localization in a saved map, on the grid package's maps);
7. ``viz``: live views;
8. ``app``: the command line, runs, outputs, plotting.

The package root imports nothing eagerly (its names load on first use). Imports inside
functions count: a lazy import is still a dependency. The landmark filters
(``feature``) import neither ``datasets`` nor ``metrics``: their kernels take arrays.
"""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "jaxslam"

LAYERS = {
    "core": 0, "models": 1, "runtime": 1, "datasets": 2, "metrics": 3, "base": 4, "feature": 5, "grid": 5,
    "filters": 6, "calibrate": 6, "localization": 6, "viz": 7, "app": 8,
}
NEVER = {"feature": {"datasets", "metrics"}}


def module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_modules() -> dict[str, pathlib.Path]:
    return {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def imports(path: pathlib.Path, modules: dict) -> set[str]:
    """The jaxslam modules ``path`` imports (``from X import Y`` counts as ``X.Y`` when
    that is a module)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.split(".")[0] == "jaxslam"}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                node.module.split(".")[0] == "jaxslam":
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.add(sub if sub in modules else node.module)
    return found


def graph() -> dict[str, set[str]]:
    modules = package_modules()
    return {name: imports(path, modules) & set(modules) - {name} for name, path in modules.items()}


def layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
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

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_every_subpackage_has_a_layer():
    assert {layer(m) for m in package_modules()} - {None} <= set(LAYERS)


def test_no_import_cycle():
    assert cycles(graph()) == []


def test_no_import_from_a_higher_layer():
    wrong = []
    for module, targets in graph().items():
        here = layer(module)
        if here is None:
            wrong += [f"{module} -> {t} (the package root imports nothing eagerly)" for t in targets]
            continue
        for target in targets:
            there = layer(target)
            if there == here:
                continue
            if there is None or LAYERS[there] >= LAYERS[here] or there in NEVER.get(here, ()):
                wrong.append(f"{module} -> {target}")
    assert wrong == []


def test_the_checks_can_fail():
    """The cycle finder and the layer order see what they are meant to see."""
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert LAYERS["core"] < LAYERS["models"] < LAYERS["datasets"] < LAYERS["feature"] < LAYERS["app"]
