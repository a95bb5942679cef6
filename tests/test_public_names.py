"""Every name the README gives the library API resolves after ``import posegraph`` alone.

The README's "Library API" says the names written ``posegraph.…`` are importable from ``posegraph``
itself: ``posegraph.X`` (a ``_LAZY`` name or a subpackage) and ``posegraph.sub.module.X`` (each
package imports its modules on first use). Its bullets also name plain functions (``graph_facts(graph)``,
``connected_components(graph)``), which are ``posegraph.X`` too. The check runs in a fresh interpreter,
each name after a fresh ``import posegraph`` (the package's modules dropped from ``sys.modules``): a
module imported by another test, or by resolving another name, would hide a missing lazy import.
"""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def package_functions() -> set[str]:
    """Names of the functions and classes defined at the top of some module of the package (methods are not)."""
    names = set()
    for path in (ROOT / "posegraph").rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names |= {node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
    return names


def dotted_names(text: str) -> set[str]:
    """``posegraph.a.b`` written anywhere in ``text`` (not inside a path such as ``posegraph/io/…``)."""
    return set(re.findall(r"(?<![\w/.])posegraph(?:\.[A-Za-z_]\w*)+", text))


def library_api_functions(text: str) -> set[str]:
    """Bare ``name(`` at the start of a code span in the Library API section, ``name`` a function of some
    module (``graph_facts(graph)``; not a method such as ``add_edges(…)`` or ``rows(graph)``): ``posegraph.name``."""
    section = text.split("## Library API", 1)[1].split("\n## ", 1)[0]
    called = set(re.findall(r"(?<![\w.])`([a-z_][a-z0-9_]*)\(", section))
    return {f"posegraph.{name}" for name in called & package_functions()}


RESOLVE = """
import importlib, json, sys
missing = {}
for name in json.loads(sys.argv[1]):
    for module in [m for m in sys.modules if m == "posegraph" or m.startswith("posegraph.")]:
        del sys.modules[module]  # each name after a fresh `import posegraph`: none imported by another's side effect
    value = importlib.import_module("posegraph")
    try:
        for part in name.split(".")[1:]:
            value = getattr(value, part)
    except AttributeError as exc:
        missing[name] = str(exc)
print(json.dumps(missing))
"""


def test_the_readme_names_are_found_by_the_parsers():
    dotted = dotted_names(README)
    functions = library_api_functions(README)
    assert {"posegraph.incremental.IncrementalOptimizer", "posegraph.model.landmarks.Landmarks", "posegraph.io.g2o"} <= dotted
    assert {"posegraph.connected_components", "posegraph.component_anchors", "posegraph.graph_facts"} <= functions
    assert "posegraph.add_edges" not in functions  # a method of IncrementalOptimizer


def test_every_name_the_readme_gives_resolves_after_import_posegraph():
    names = sorted(dotted_names(README) | library_api_functions(README))
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-c", RESOLVE, json.dumps(names)], capture_output=True, text=True,
                         cwd=ROOT, env=environment, timeout=120)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == {}


def test_unknown_names_still_raise_attribute_error():
    import posegraph

    assert not hasattr(posegraph, "no_such_name")
    assert not hasattr(posegraph.io, "no_such_module")
    assert not hasattr(posegraph, "_private")
