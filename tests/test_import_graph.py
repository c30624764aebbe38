"""The package's modules import each other without circles, deferred imports inside functions and imports for
annotations only (``if TYPE_CHECKING:``) included: a circle that only those hide still ties the modules into one.
And the folders follow the data flow: no stage imports a later one (docs/architecture.md)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "insertnerf_cli"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """module -> the package modules it imports (from-imports of a submodule count as that submodule)."""
    files = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text())
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        deps: set[str] = set()
        for node in ast.walk(tree):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = package[:len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.split(".")[0] == PACKAGE.name:
                target = node.module
            else:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                deps.add(sub if sub in files else target)
        graph[name] = {d for d in deps if d in files and d != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = stack[stack.index(v):]
            del stack[stack.index(v):]
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_cycle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


@pytest.mark.slow
def test_graph_sees_relative_and_deferred_imports():
    graph = import_graph()
    assert "insertnerf_cli.scenes.images" in graph["insertnerf_cli.scenes.base"]
    assert "insertnerf_cli.finetune" in graph["insertnerf_cli.pipelines.inputs"]


@pytest.mark.slow
def test_no_import_circles():
    assert cycles(import_graph()) == []


# The stages in data-flow order: a module may import its own stage and earlier ones, never a later one.
STAGES = ["errors", "interrupts", "config", "files", "cameras", "metrics", "scenes", "synth", "poses", "model", "sfm",
          "rendering", "training", "finetune", "exporters", "pipelines", "cli"]


def _stage(module: str) -> int:
    parts = module.split(".")
    return STAGES.index(parts[1]) if len(parts) > 1 else -1  # the package's own __init__ comes first


@pytest.mark.slow
def test_every_module_belongs_to_a_stage():
    assert {m.split(".")[1] for m in import_graph() if "." in m} <= set(STAGES)


@pytest.mark.slow
def test_no_stage_imports_a_later_one():
    later = sorted(f"{module} -> {dep}" for module, deps in import_graph().items() for dep in deps
                   if _stage(dep) > _stage(module))
    assert later == []


@pytest.mark.slow
def test_the_model_depends_on_no_render_path_stage():
    deps = {dep.split(".")[1] for module, ds in import_graph().items() if module.startswith("insertnerf_cli.model")
            for dep in ds if "." in dep}
    assert not deps & {"sfm", "rendering", "pipelines", "exporters", "training", "finetune"}


def test_the_package_top_holds_few_modules():
    assert len(list(PACKAGE.glob("*.py"))) <= 8
