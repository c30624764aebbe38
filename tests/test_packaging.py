"""Every third-party module the project imports is declared in pyproject.toml, so a fresh install can run it.

The imports are read with ``ast`` (top level and inside functions); each module name is mapped to the
distributions that provide it in this environment (importlib.metadata) and must meet one declared for its folder:
runtime dependencies for the package, bench/ and scripts/; runtime plus the ``test`` extra for tests/.
"""
from __future__ import annotations

import ast
import importlib.metadata
import re
import sys
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"insertnerf_cli": (), "bench": (), "scripts": (), "tests": ("test",)}  # folder -> extras it may use


def canonical(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def declared(extras: tuple[str, ...]) -> set[str]:
    """Canonical names of pyproject's runtime dependencies plus the given extras."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    for extra in extras:
        requirements += project["optional-dependencies"][extra]
    return {canonical(re.match(r"[A-Za-z0-9._-]+", req).group()) for req in requirements}


def imported_modules(source: str) -> set[str]:
    """Top-level names of every absolute import in ``source``, wherever it stands."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def local_modules() -> set[str]:
    """Our own importable names: the package, and the modules that tests/ and bench/ import from each other."""
    return {"insertnerf_cli"} | {path.stem for folder in FOLDERS for path in (ROOT / folder).glob("*.py")}


def undeclared(modules: set[str], allowed: set[str], providers: dict[str, list[str]]) -> list[str]:
    """The third-party modules among ``modules`` that no distribution in ``allowed`` provides."""
    third_party = sorted(modules - set(sys.stdlib_module_names) - local_modules() - {"__future__"})
    return [m for m in third_party if not {canonical(d) for d in providers.get(m, [])} & allowed]


@pytest.mark.slow
@pytest.mark.parametrize("folder", sorted(FOLDERS))
def test_every_imported_module_is_declared(folder: str) -> None:
    providers = importlib.metadata.packages_distributions()
    allowed = declared(FOLDERS[folder])
    missing = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        for module in undeclared(imported_modules(path.read_text()), allowed, providers):
            missing.setdefault(module, []).append(str(path.relative_to(ROOT)))
    assert not missing, f"imported but not declared in pyproject.toml for {folder}/: {missing}"


@pytest.mark.slow
def test_every_runtime_dependency_is_imported() -> None:
    """No stale dependency: each declared runtime distribution provides a module the package imports."""
    providers = importlib.metadata.packages_distributions()
    modules = set().union(*(imported_modules(p.read_text()) for p in (ROOT / "insertnerf_cli").rglob("*.py")))
    provided = {canonical(d) for m in modules for d in providers.get(m, [])}
    assert declared(()) - provided == set()


def test_the_check_catches_an_undeclared_import() -> None:
    """The checker itself: scipy imported inside a function, with scipy not declared, is reported."""
    source = "import os\nfrom . import cameras\ndef f():\n    from scipy.spatial import cKDTree\n    import numpy\n"
    providers = {"scipy": ["scipy"], "numpy": ["numpy"]}
    assert undeclared(imported_modules(source), {"numpy"}, providers) == ["scipy"]
    assert undeclared(imported_modules(source), {"numpy", "scipy"}, providers) == []
