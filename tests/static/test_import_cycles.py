"""No import cycle in the ``snan_hil`` package, not even through a function-level import.

The graph has one node per module of the package (the packages listed in pyproject.toml) and
one edge per ``import`` / ``from ... import`` statement naming another module of the package,
wherever the statement is: at module level, inside a function or a class, under ``try``, and
under ``if TYPE_CHECKING:`` (such an import never runs, but two modules whose annotations name
each other's types are as entangled as two that call each other: the shared type belongs in a
module both import; bench/bench_structure.py counts them alike). A ``from a.b import c`` is an
edge to ``a.b.c`` when that is a module, else to ``a.b``. The implicit imports of parent
packages are left out (a package's ``__init__`` importing its own sub-modules is how packages
load, not a cycle). Any strongly connected component of more than one module is a cycle: the
test names its modules and the import statements (file:line) that close it.
"""

from __future__ import annotations

import ast
import os
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Edge:
    target: str
    where: str                      # file:line of the import statement
    in_function: bool
    type_checking: bool = False     # under ``if TYPE_CHECKING:`` (annotations only)


def package_modules(root: Path, packages: Iterable[str],
                    package_dir: str = ".") -> dict[str, Path]:
    """{dotted module name: file} of every module of ``packages`` (dotted names; the first
    component is the distribution's root package, found at ``root / package_dir``)."""
    mods: dict[str, Path] = {}
    for pkg in packages:
        folder = root / package_dir / Path(*pkg.split(".")[1:])
        for path in sorted(folder.glob("*.py")):
            mods[pkg if path.stem == "__init__" else f"{pkg}.{path.stem}"] = path
    return mods


def _type_checking_only(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    while node in parents:
        node = parents[node]
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            return True
    return False


def _in_function(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    while node in parents:
        node = parents[node]
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            return True
    return False


def _targets(module: str, is_package: bool, node: ast.Import | ast.ImportFrom,
             mods: dict[str, Path]) -> list[str]:
    if isinstance(node, ast.Import):
        out = []
        for alias in node.names:
            name = alias.name
            while name and name not in mods:          # import a.b.c: the deepest module known
                name = name.rpartition(".")[0]
            if name:
                out.append(name)
        return out
    if node.level:                                    # relative: from .x import y
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[:len(base) - (node.level - 1)]
        source = ".".join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    out = []
    for alias in node.names:
        sub = f"{source}.{alias.name}"
        if sub in mods:
            out.append(sub)
        elif source in mods:
            out.append(source)
    return out


def import_graph(mods: dict[str, Path]) -> dict[str, dict[str, Edge]]:
    """{module: {imported module: the first statement importing it}}."""
    graph: dict[str, dict[str, Edge]] = {m: {} for m in mods}
    top = Path(os.path.commonpath(list(mods.values())))
    for module, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for target in _targets(module, path.name == "__init__.py", node, mods):
                if target != module and target not in graph[module]:
                    graph[module][target] = Edge(target, f"{path.relative_to(top)}:{node.lineno}",
                                                 _in_function(node, parents),
                                                 _type_checking_only(node, parents))
    return graph


def cycles(graph: dict[str, dict[str, Edge]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(graph[child])))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def describe(component: list[str], graph: dict[str, dict[str, Edge]]) -> str:
    members = set(component)
    lines = [f"import cycle of {len(component)} modules: {', '.join(component)}"]
    for module in component:
        for target, edge in sorted(graph[module].items()):
            if target in members:
                kind = ("function-level " if edge.in_function else "") + \
                    ("TYPE_CHECKING " if edge.type_checking else "")
                lines.append(f"  {module} -> {target} ({kind}import at {edge.where})")
    return "\n".join(lines)


def function_level_imports(mods: dict[str, Path]) -> list[tuple[str, str, bool]]:
    """Every import statement inside a function: (file:line, statement, names a module of the
    package)."""
    top = Path(os.path.commonpath(list(mods.values())))
    found = []
    for module, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)) and _in_function(node, parents):
                own = bool(_targets(module, path.name == "__init__.py", node, mods))
                found.append((f"{path.relative_to(top)}:{node.lineno}", ast.unparse(node), own))
    return sorted(found)


def _project_modules() -> dict[str, Path]:
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    package_dir = setup["package-dir"]["snan_hil"]
    return package_modules(ROOT, setup["packages"], package_dir)


def test_the_package_has_no_import_cycle():
    mods = _project_modules()
    assert len(mods) > 150, f"only {len(mods)} modules found: the package list was misread"
    graph = import_graph(mods)
    found = cycles(graph)
    assert not found, "\n".join(describe(c, graph) for c in found)


def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_cycle_through_a_function_level_import_is_found(tmp_path):
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/a.py": "from pkg.b import g\n",
        "pkg/b.py": "def g():\n    from pkg import c\n    return c\n",
        "pkg/c.py": "import pkg.a\n",
        "pkg/d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import a\n",
        "pkg/e.py": "from pkg.d import x\n",
        "pkg/sub/__init__.py": "from . import f\n",
        "pkg/sub/f.py": "from ..e import y\n",
    })
    mods = package_modules(tmp_path, ["pkg", "pkg.sub"], package_dir="pkg")
    graph = import_graph(mods)
    found = cycles(graph)
    assert found == [["pkg.a", "pkg.b", "pkg.c"]]
    text = describe(found[0], graph)
    assert "pkg.b -> pkg.c (function-level import at b.py:2)" in text, text
    assert "pkg.a -> pkg.b (import at a.py:1)" in text
    assert set(graph["pkg.d"]) == {"pkg.a"}          # TYPE_CHECKING: an edge too
    assert graph["pkg.d"]["pkg.a"].type_checking
    assert set(graph["pkg.sub"]) == {"pkg.sub.f"}   # relative imports resolved
    assert set(graph["pkg.sub.f"]) == {"pkg.e"}


def test_a_cycle_through_a_type_checking_import_is_found(tmp_path):
    """Two modules naming each other's types (the shape of the three cycles issue 32 found:
    programmer <-> program_report, firmware <-> spike_fastpath, mcu_isa -> mik32_native ->
    mik32_periph -> mcu_isa) are a cycle even though the import never runs."""
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/job.py": "from pkg.report import build\n",
        "pkg/report.py": ("from typing import TYPE_CHECKING\n"
                          "if TYPE_CHECKING:\n    from pkg.job import Config\n"
                          "def build(cfg: 'Config') -> None: ...\n"),
        "pkg/config.py": "class Config: ...\n",
    })
    mods = package_modules(tmp_path, ["pkg"], package_dir="pkg")
    graph = import_graph(mods)
    found = cycles(graph)
    assert found == [["pkg.job", "pkg.report"]]
    assert "pkg.report -> pkg.job (TYPE_CHECKING import at report.py:3)" in \
        describe(found[0], graph)
    # the cure: the shared type in the module both import
    _write(tmp_path, {"pkg/report.py": ("from pkg.config import Config\n"
                                        "def build(cfg: Config) -> None: ...\n"),
                      "pkg/job.py": ("from pkg.config import Config\n"
                                     "from pkg.report import build\n")})
    assert cycles(import_graph(mods)) == []


if __name__ == "__main__":          # the counts: python tests/static/test_import_cycles.py [-v]
    import sys
    modules = _project_modules()
    graph = import_graph(modules)
    lazy = function_level_imports(modules)
    print(f"{len(modules)} modules, {sum(map(len, graph.values()))} import edges, "
          f"{len(lazy)} function-level import statements ({sum(o for *_, o in lazy)} of the "
          f"package's own modules), {len(cycles(graph))} cycles")
    if "-v" in sys.argv:
        for where, text, _own in lazy:
            print(f"  {where}: {text}")
    for component in cycles(graph):
        print(describe(component, graph))
