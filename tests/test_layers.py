"""The package's layers: every import runs down (or stays in its folder), no module imports cli/, and
no two modules import each other, directly or round a loop (imports inside functions included).

A folder's place is LAYERS below; a new folder needs a line there, which is the point: deciding
what it may use. `footskate` is a layer of its own under everything and never imports stablemo.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# lowest first; a unit (a folder or a top-level module of stablemo) may import its own layer's
# units and those below it
LAYERS = [
    ("errors",),
    ("checks", "io"),
    ("motion",),
    ("text", "diffusion", "bvh", "gltf"),  # gltf: motion and bvh only (stablemo/gltf)
    ("nets", "skating", "outputs"),
    ("fast", "distill", "control", "data", "retarget"),  # retarget: motion, bvh, gltf (stablemo/retarget)
    ("timeline",),
    ("inference",),
    ("official", "training"),
    ("eval",),
    ("serve", "bench"),
    ("cli",),
    ("__init__",),  # the front door names the public API of every layer
]
RANK = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}


def module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def imports(path: Path, modules: set[str] = frozenset()) -> set[str]:
    """Every module `path` imports (module-level or inside functions). `from package import sub`
    imports the module package.sub when `modules` knows it (the package's face is not counted then:
    it only hands names on), else the names of `package` itself."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{alias.name}" for alias in node.names} & set(modules)
            found.update(subs)
            if len(subs) < len(node.names):
                found.add(node.module)
    return found


def graph(package: str) -> dict[str, set[str]]:
    files = {module_name(p): p for p in (ROOT / package).rglob("*.py")}
    return {name: {m for m in imports(path, set(files)) if m in files and m != name} for name, path in files.items()}


def unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def find_circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of two or more modules (Tarjan): each is an import circle."""
    index, low, stack, on_stack, circles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
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
                circles.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return circles


def upward_imports(edges: dict[str, set[str]]) -> list[str]:
    return sorted(f"{a} -> {b}" for a, targets in edges.items() for b in targets if RANK[unit(b)] > RANK[unit(a)])


@pytest.mark.parametrize("package", ["stablemo", "footskate"])
def test_no_import_circles(package):
    circles = find_circles(graph(package))
    assert not circles, f"import circles: {circles}"


def test_every_import_runs_down_the_layers():
    edges = graph("stablemo")
    units = {unit(m) for m in edges}
    assert units <= set(RANK), f"folders without a layer (add them to LAYERS): {sorted(units - set(RANK))}"
    upward = upward_imports(edges)
    assert not upward, "imports running up the layers:\n" + "\n".join(sorted(upward))


def test_nothing_below_cli_imports_it_or_parses_argv():
    edges = graph("stablemo")
    into_cli = [f"{a} -> {b}" for a, targets in edges.items() for b in targets
                if unit(b) == "cli" and unit(a) not in ("cli", "__init__")]
    assert not into_cli, f"library modules importing stablemo.cli: {into_cli}"
    parsers = [module_name(p) for p in (ROOT / "stablemo").rglob("*.py")
               if unit(module_name(p)) != "cli" and "ArgumentParser(" in p.read_text(encoding="utf-8")]
    assert not parsers, f"argument parsing outside stablemo/cli: {parsers}"


def test_footskate_never_imports_stablemo():
    offenders = [module_name(p) for p in (ROOT / "footskate").rglob("*.py")
                 if any(m == "stablemo" or m.startswith("stablemo.") for m in imports(p))]
    assert not offenders, f"footskate modules importing stablemo: {offenders}"


def test_the_checks_can_fail():
    """The circle finder and the layer rule on made-up graphs: a loop and an upward import are seen."""
    loop = {"stablemo.motion.a": {"stablemo.motion.b"}, "stablemo.motion.b": {"stablemo.motion.c"},
            "stablemo.motion.c": {"stablemo.motion.a"}, "stablemo.motion.d": {"stablemo.motion.a"}}
    assert find_circles(loop) == [["stablemo.motion.a", "stablemo.motion.b", "stablemo.motion.c"]]
    assert find_circles({"x": {"y"}, "y": set()}) == []
    up = {"stablemo.motion.features": {"stablemo.inference.pipeline"}, "stablemo.inference.pipeline": set()}
    assert upward_imports(up) == ["stablemo.motion.features -> stablemo.inference.pipeline"]
    assert upward_imports({"stablemo.inference.pipeline": {"stablemo.motion.features"}}) == []
