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
import importlib.util
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


def _cycle_check():
    """The suite's import-cycle check (tests/static/test_import_cycles.py: the import graph
    with function-level and TYPE_CHECKING imports, and its cycles), loaded from its file so
    the bench counts exactly what the suite refuses."""
    spec = importlib.util.spec_from_file_location(
        "snan_hil_import_cycle_check", ROOT / "tests" / "static" / "test_import_cycles.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module           # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


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
    check = _cycle_check()
    graph = check.import_graph(check._project_modules())
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
            "import_cycles": check.cycles(graph),
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
