"""The package's floors: every module of ``posegraph/`` sits on one floor, named for its job, and imports
only from its own floor or the floors below it; no two modules import each other, even through others.

Imports are read from the source (``ast``), wherever they are: at the top of a module or inside a
function (the lazy imports that keep start-up cheap are imports all the same), plus
``importlib.import_module`` with a literal name. The floors, bottom to top (docs/architecture.md):
"""

from __future__ import annotations

import ast
import graphlib
import importlib.util
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "posegraph"

FLOORS = (
    ("errors",),  # the error types, the one module at the root beside the package's face
    ("lie",),  # Lie groups: SO(2), SE(2), SO(3), SE(3), Sim(3)
    ("linalg",),  # sparse backends: CHOLMOD and orders, multigrid CG, BLAS threads, memory
    ("model",),  # the pose graph and its priors
    ("io",),  # files: g2o, TUM/KITTI, compressed input, atomic output, Open3D export
    ("init",),  # starts: chordal, odometry
    ("solve",),  # the trust-region solver (it starts from init)
    ("crosscheck",),  # gtsam beside ours: the bridge, the Jacobian checks
    ("robust", "certification", "analysis"),  # GNC; SE-Sync's certificate; covariances, metrics, reports, plots
    ("incremental",),  # the incremental optimiser (it reads covariances from analysis)
    ("cli", "batch"),  # the command, and batch, which runs the command over many files
)
"""Folders on one floor may import each other's modules (only ``cli`` and ``batch`` do: the command has
a ``batch`` subcommand, and batch runs the command in each worker), never in a cycle."""

FACE = ("__init__", "__main__")
"""The package's face at its root: ``posegraph/__init__.py`` names the public API as strings, imported on
first use (it imports no module of the package itself), ``__main__`` runs the command. Any module may read
``posegraph.__version__``, and a subpackage's ``__init__`` takes its ``__getattr__`` from
``posegraph.submodule_getattr``; nothing else of the face."""

FLOOR = {room: level for level, rooms in enumerate(FLOORS) for room in rooms}
TOP = len(FLOORS)


def _modules() -> dict[str, Path]:
    """``dotted name -> path`` of every module of the package (a package by its ``__init__``)."""
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


MODULES = _modules()


def _absolute(node: ast.ImportFrom, name: str, path: Path) -> str:
    """The absolute module an ``ImportFrom`` in module ``name`` names (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _literal_import(node: ast.Call) -> str | None:
    """``"posegraph.x"`` of ``importlib.import_module("posegraph.x")``, else None."""
    func = node.func
    called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if called == "import_module" and node.args and isinstance(node.args[0], ast.Constant):
        return node.args[0].value
    return None


def imports(name: str) -> set[tuple[str, str | None]]:
    """``(module, imported name or None)`` for every import of a package module by module ``name``."""
    path = MODULES[name]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found |= {(alias.name, None) for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            module = _absolute(node, name, path)
            for alias in node.names:
                submodule = f"{module}.{alias.name}"
                found.add((submodule, None) if submodule in MODULES else (module, alias.name))
        elif isinstance(node, ast.Call) and (module := _literal_import(node)):
            found.add((module, None))
    return {(module, what) for module, what in found if module == "posegraph" or module.startswith("posegraph.")}


def floor(name: str) -> int:
    """The floor of module ``name``: its folder's (or, at the root, its own)."""
    room = name.split(".")[1] if "." in name else "__init__"
    return TOP if room in FACE else FLOOR[room]


def test_every_folder_and_root_module_has_a_floor():
    rooms = {name.split(".")[1] for name in MODULES if "." in name}
    assert rooms == set(FLOOR) | {"__main__"}, "a new folder needs its floor in FLOORS (and docs/architecture.md)"


def test_the_root_holds_only_the_face_and_the_error_types():
    assert sorted(path.name for path in PACKAGE.glob("*.py")) == ["__init__.py", "__main__.py", "errors.py"]


def test_no_import_from_a_higher_floor():
    upward = []
    for name in MODULES:
        for module, what in imports(name):
            if module == "posegraph":  # the face: its version and the subpackages' lazy __getattr__ only
                if what not in ("__version__", "submodule_getattr"):
                    upward.append(f"{name} imports posegraph.{what} (the face: import it from its module)")
            elif floor(module) > floor(name):
                upward.append(f"{name} (floor {floor(name)}) imports {module} (floor {floor(module)})")
    assert not upward, "\n".join(sorted(upward))


def test_no_import_cycle():
    graph = {name: {module for module, _ in imports(name) if module in MODULES} - {name, "posegraph"} for name in MODULES}
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as err:
        pytest.fail(f"import cycle: {' -> '.join(err.args[1])}")


def test_the_face_imports_no_module_of_the_package_when_imported():
    """``import posegraph`` runs no import of the package: its names are strings, imported on first use."""
    body = ast.parse((PACKAGE / "__init__.py").read_text(encoding="utf-8")).body
    top = [node for node in body if isinstance(node, (ast.Import, ast.ImportFrom))]
    assert all(not (getattr(node, "module", None) or node.names[0].name).startswith("posegraph") for node in top)


def test_the_public_names_point_at_their_modules():
    """Every lazy name of ``posegraph/__init__.py`` is defined at the top of the module it names."""
    import posegraph

    for public, module in posegraph._LAZY.items():
        spec = importlib.util.find_spec(module)
        assert spec is not None, module
        tree = ast.parse(Path(spec.origin).read_text(encoding="utf-8"))
        defined = set()
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                defined.add(node.name)
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                defined |= {(alias.asname or alias.name).split(".")[0] for alias in node.names}
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                defined |= {t.id for t in targets if isinstance(t, ast.Name)}
        assert public in defined, f"posegraph.{public}: not defined in {module}"
