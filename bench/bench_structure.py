"""The structure figures issue 32 asks about, measured on the tree, printed beside their targets.

    .venv/bin/python bench/bench_structure.py [--json]

* the longest function in ``host/hil/`` and in ``tools/commands/`` (lines), and the longest
  command ``run`` (target: a command is parse -> job config -> runner -> print, ~40 lines);
* the places that derive the write limit from a board's INFO (target 1: the client's
  ``limits``), counted as calls of ``HostLimits.from_board`` / ``check_max_write_v`` /
  ``CellLimits.of`` outside the one place each belongs (the client, the session's address
  check, the bench);
* the construction sites of ``PulseLedger(``, ``BoardCellIO(``, ``ControlledClient(`` /
  ``controlled(``, ``Recorder(`` outside the runner and the bench (target 0);
* module import cycles, counting imports inside functions too (target 0);
* the lines of ``tools/commands/``.

Near-duplicate pairs are counted by the tool library's ``duplicates`` (not part of the
project), so they are not here.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "snan_hil"
SKIP = {"tests", "bench", "docs", "build", ".venv", "conformance", "firmware"}
OWNERS = {"lab/runner.py", "lab/fanout.py", "calibration/bench.py", "calibration/board_io.py",
          "calibration/control.py", "records/history.py"}
"""Where the construction of the run's pieces belongs (the engine and the classes' own
modules)."""


def modules() -> dict[str, Path]:
    """Module name -> file, for every module of the package (tests, benches left out)."""
    out: dict[str, Path] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[0] in SKIP or any(p.startswith(".") for p in rel.parts):
            continue
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join([PACKAGE, *parts])] = path
    return out


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The package modules ``path`` imports, at module level or inside functions."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: set[str] = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base]) if base else ".".join(up)
            subs = [f"{base}.{a.name}" for a in node.names]
            # ``from pkg import module``: the module, not the package's __init__ (which
            # Python imports first anyway, whatever the importer)
            targets = [t for t in subs if t in known] or [base]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name and t != PACKAGE:
                found.add(t)
    return found


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))
    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def longest(folder: str, only: str | None = None) -> tuple[int, str]:
    best = (0, "")
    for path in sorted((ROOT / folder).glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and \
                    (only is None or node.name == only):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > best[0]:
                    best = (n, f"{path.relative_to(ROOT)}:{node.name}")
    return best


def call_sites(names: tuple[str, ...], allowed: set[str]) -> list[str]:
    out = []
    for path in modules().values():
        rel = str(path.relative_to(ROOT))
        if rel in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call):
                f = node.func
                called = f.attr if isinstance(f, ast.Attribute) else \
                    f.id if isinstance(f, ast.Name) else ""
                dotted = f"{f.value.id}.{f.attr}" if isinstance(f, ast.Attribute) and \
                    isinstance(f.value, ast.Name) else called
                if called in names or dotted in names:
                    out.append(f"{rel}:{node.lineno} {dotted}")
    return out


def measure() -> dict[str, object]:
    mods = modules()
    known = set(mods)
    graph = {m: imports_of(m, p, known) for m, p in mods.items()}
    limit_sites = call_sites(("HostLimits.from_board", "check_max_write_v", "CellLimits.of",
                              "BoardLimits.for_board"),
                             {"protocol/client.py", "protocol/safety.py", "lab/ports.py",
                              "calibration/bench.py", "calibration/board_io.py"})
    wiring = call_sites(("PulseLedger", "BoardCellIO", "ControlledClient", "controlled",
                         "Recorder", "open_recorder"), OWNERS)
    cmd_lines = sum(len(p.read_text(encoding="utf-8").splitlines())
                    for p in (ROOT / "tools" / "commands").glob("*.py"))
    return {"longest_host_hil": longest("host/hil"),
            "longest_tools_commands": longest("tools/commands"),
            "longest_command_run": longest("tools/commands", only="run"),
            "write_limit_derivations_outside_their_owner": limit_sites,
            "wiring_sites_outside_the_engine": wiring,
            "import_cycles": cycles(graph),
            "tools_commands_lines": cmd_lines}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    m = measure()
    if args.json:
        print(json.dumps(m, indent=1))
        return 0
    rows = [
        ("longest function in host/hil/", f"{m['longest_host_hil'][0]} "
         f"({m['longest_host_hil'][1]})", "-"),
        ("longest function in tools/commands/", f"{m['longest_tools_commands'][0]} "
         f"({m['longest_tools_commands'][1]})", "-"),
        ("longest command run()", f"{m['longest_command_run'][0]} "
         f"({m['longest_command_run'][1]})", "<= ~40"),
        ("write-limit derivations outside their owner",
         str(len(m["write_limit_derivations_outside_their_owner"])), "0"),  # type: ignore
        ("PulseLedger/BoardCellIO/controlled/Recorder sites outside the engine",
         str(len(m["wiring_sites_outside_the_engine"])), "0"),  # type: ignore[arg-type]
        ("import cycles (function-level imports included)",
         str(len(m["import_cycles"])), "0"),  # type: ignore[arg-type]
        ("lines of tools/commands/", str(m["tools_commands_lines"]), "-"),
    ]
    width = max(len(r[0]) for r in rows)
    print(f"{'figure':<{width}}  {'measured':<60}  target")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:<60}  {target}")
    for key in ("write_limit_derivations_outside_their_owner", "wiring_sites_outside_the_engine"):
        for site in m[key]:  # type: ignore[attr-defined]
            print(f"  {key}: {site}")
    for cyc in m["import_cycles"]:  # type: ignore[attr-defined]
        print("  cycle: " + " -> ".join(cyc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
