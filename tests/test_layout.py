"""The package's layout rules (README, "Layout"): sizes, no import cycle, no private imports.

Static checks of the source (no import of the package): every module of ``shoulder_fem/`` stays
under the size bounds, the module import graph has no cycle (function-level imports included),
and no module imports another module's underscore name.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "shoulder_fem"
#: ``shoulder_fem.forms`` and ``shoulder_fem.meshes`` live here (pyproject.toml, package-dir)
MAPPED = {"shoulder_fem.forms": ROOT / "forms", "shoulder_fem.meshes": ROOT / "meshes"}
MAX_MODULE_LINES = 600
MAX_CLASS_LINES = 300
MAX_FUNCTION_LINES = 80


def _modules() -> dict[str, Path]:
    """Module name -> file, for the package and the mapped folders."""
    found = {}
    roots = [("shoulder_fem", PACKAGE), *MAPPED.items()]
    for prefix, folder in roots:
        for path in folder.rglob("*.py"):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join([prefix, *parts])] = path
    return found


MODULES = _modules()


def _resolve(module: str, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    is_package = MODULES[module].name == "__init__.py"
    base = module.split(".")
    base = base if is_package else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _runtime_nodes(tree: ast.AST):
    """Every node except those under ``if TYPE_CHECKING:`` (imports for annotations only)."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            continue
        yield node
        yield from _runtime_nodes(node)


def _imports(module: str) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) of every run-time import in ``module``."""
    tree = ast.parse(MODULES[module].read_text())
    out = []
    for node in _runtime_nodes(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, None, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, node)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:
                    out.append((sub, None, node.lineno))
                else:
                    out.append((target, alias.name, node.lineno))
    return [(m, n, line) for m, n, line in out if m.startswith("shoulder_fem")]


def test_sizes_of_modules_classes_and_functions():
    too_big = []
    for name, path in MODULES.items():
        if not name.startswith("shoulder_fem.") or name.split(".")[1] in ("forms", "meshes"):
            continue  # forms/ and meshes/ keep their own shape (README, "Layout")
        text = path.read_text()
        lines = text.count("\n")
        if lines > MAX_MODULE_LINES:
            too_big.append(f"{name}: {lines} lines > {MAX_MODULE_LINES}")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                limit = MAX_CLASS_LINES if isinstance(node, ast.ClassDef) else MAX_FUNCTION_LINES
                size = node.end_lineno - node.lineno + 1
                if size > limit:
                    too_big.append(f"{name}.{node.name}: {size} lines > {limit}")
    assert not too_big, "\n".join(too_big)


def test_no_import_of_another_modules_private_name():
    private = []
    for name in MODULES:
        for target, imported, line in _imports(name):
            if target == name:
                continue
            if imported and imported.startswith("_") and imported != "__version__":
                private.append(f"{MODULES[name].name}:{line} imports {target}.{imported}")
            if any(part.startswith("_") and part != "__init__" for part in target.split(".")):
                private.append(f"{MODULES[name].name}:{line} imports private module {target}")
    assert not private, "\n".join(private)


def test_no_import_cycle():
    graph = {
        name: sorted({t for t, _, _ in _imports(name) if t in MODULES and t != name})
        for name in MODULES
    }
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in graph[node]:
            if state.get(nxt) == 1:
                cycles.append(" -> ".join(stack[stack.index(nxt) :] + [nxt]))
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node)
    assert not cycles, "\n".join(cycles)


@pytest.mark.parametrize("name", ["shoulder_fem", "shoulder_fem.cli"])
def test_import_has_no_side_effects(name):
    import subprocess
    import sys

    code = (
        f"import os, sys; import {name}; "
        "print(sorted(m for m in ('numpy', 'mpi4py', 'dolfinx', 'matplotlib') if m in sys.modules),"
        " os.environ.get('OMP_NUM_THREADS'))"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k != "OMP_NUM_THREADS"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.strip() == "[] None"


def test_every_package_is_installed():
    """pyproject.toml lists each package explicitly (package-dir maps forms/ and meshes/)."""
    import tomllib

    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {name for name, path in MODULES.items() if path.name == "__init__.py"}
    assert found == listed, f"missing: {sorted(found - listed)}, extra: {sorted(listed - found)}"


#: What each layer may import from the package (README, "Layout"): data flows one way.
ALLOWED = {
    "forms": {"forms"},
    "meshes": {"meshes", "forms"},
    "units": {"units"},
    "scene": {"scene", "units"},
    "engine": {"engine", "forms", "meshes"},
    "io": {"io", "forms", "meshes"},
    "families": {"families", "engine", "io", "forms", "meshes", "scene", "units"},
    "studies": {"studies", "families", "io", "scene"},
    "api": {"api", "studies", "families", "io", "engine", "scene", "units"},
    "cli": {"cli", "api", "families", "io", "engine", "scene", "meshes", "units"},
}


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_layers_import_only_downwards():
    wrong = []
    for name in MODULES:
        layer = _layer(name)
        if layer not in ALLOWED:
            continue  # the package root: its names are lazy (no run-time import)
        for target, _, line in _imports(name):
            if target != "shoulder_fem" and _layer(target) not in ALLOWED[layer]:
                wrong.append(f"{MODULES[name].relative_to(ROOT)}:{line} ({layer}) imports {target}")
    assert not wrong, "\n".join(wrong)


#: Third-party modules that Debian 12 provides and pip cannot build (scripts/setup.sh installs
#: them; pyproject.toml says so).
DEBIAN_ONLY = {"dolfinx", "petsc4py", "mpi4py", "ufl", "basix", "ffcx", "gmsh"}
#: Modules that a declared distribution of another name provides.
PROVIDED_BY = {"mpl_toolkits": "matplotlib"}


def test_every_third_party_import_is_declared():
    """Every third-party module the package imports is a declared dependency of pyproject.toml
    or one of the Debian-only packages: a user who installs it elsewhere learns what it needs."""
    import sys
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {
        d.split(">")[0].split("=")[0].split("[")[0].strip() for d in project["dependencies"]
    }
    used = set()
    for folder in ("shoulder_fem", "meshes", "forms"):
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    used |= {a.name.split(".")[0] for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    used.add(node.module.split(".")[0])
    third_party = {
        m
        for m in used
        if m not in sys.stdlib_module_names and m not in {"shoulder_fem", "meshes", "forms"}
    }
    assert third_party, used
    undeclared = {m for m in third_party - DEBIAN_ONLY if PROVIDED_BY.get(m, m) not in declared}
    assert not undeclared, sorted(undeclared)
