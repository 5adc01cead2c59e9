"""Seeded faults in the firmware's C sources, for mutation testing (bench/bench_mutation.py).

:func:`mutants` reads ``firmware/src/*.c`` as they are now (whatever another branch changed)
and proposes one-line faults of four kinds, as a careless edit would make them:

* ``off-by-one`` - a comparison in a condition made inclusive or exclusive (``<`` <-> ``<=``,
  ``>`` <-> ``>=``);
* ``register bit`` - a use of a register bit (a ``(1u << n)`` macro of ``mik32_regs.h`` or a
  74HC595 bit of the generated constants header) moved to the next bit;
* ``dropped check`` - the condition of an ``if`` that returns, refuses or breaks made false
  (``if (0 && (...))``), so the check is skipped;
* ``swapped operands`` - the two operands of a subtraction or of a comparison exchanged.

Each :class:`Mutant` changes exactly one occurrence on one line; :func:`pick` takes a seeded,
spread sample of each kind. :func:`apply` gives the mutated file text. No compiler here.
"""

from __future__ import annotations

import random
import re
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Mutant", "KINDS", "mutants", "pick", "apply"]

HERE = Path(__file__).resolve().parent
KINDS = ("off-by-one", "register bit", "dropped check", "swapped operands")
_SOURCES = ("proto.c", "ops.c", "window.c", "hal_mik32.c", "main.c")
_CMP = re.compile(r"(?<![<>=!-])(<=|>=|<|>)(?![<>=])")
_IF = re.compile(r"\bif \((.*)\)\s*(return|break|goto|\{|continue|[a-z_]+\()")
_SUB = re.compile(r"\b([A-Za-z_][A-Za-z_0-9.\[\]]*) - ([A-Za-z_][A-Za-z_0-9.\[\]]*)\b")
_REL = re.compile(r"\b([A-Za-z_][A-Za-z_0-9]*) (<|>|<=|>=) ([A-Za-z_][A-Za-z_0-9]*)\b(?!\s*[(\[.])")
_KEYWORDS = frozenset(("sizeof", "return", "unsigned", "int", "uint8_t", "uint16_t", "uint32_t",
                       "const", "if", "while", "for", "else"))


@dataclass(frozen=True)
class Mutant:
    """One fault: ``file`` (under ``src/``), ``line`` (1-based), the whole line ``before`` and
    ``after``, its ``kind``."""

    file: str
    line: int
    kind: str
    before: str
    after: str

    @property
    def name(self) -> str:
        return f"{self.file}:{self.line} {self.kind}"


def _bit_names(src: Path, header: Path | None) -> set[str]:
    names = set(re.findall(r"#define (\w+)\s+\(1u << \d+\)", (src / "mik32_regs.h").read_text()))
    if header is not None and header.is_file():
        names |= set(re.findall(r"#define (SR_\w+_EN|SR_SUM_PATH|SR_POL_SET|SR_PULSE_GATE)\s",
                                header.read_text()))
    return names


def _code(line: str) -> bool:
    s = line.strip()
    return bool(s) and not s.startswith(("//", "/*", "*", "#"))


def mutants(src: Path = HERE / "src", header: Path | None = None) -> list[Mutant]:
    """Every candidate fault in the sources (module docstring); ``header``: the generated
    ``snan_constants.h`` (its 74HC595 bits; None: the register bits of ``mik32_regs.h``
    only)."""
    bits = _bit_names(src, header)
    bit_re = re.compile(r"\b(" + "|".join(sorted(bits)) + r")\b") if bits else None
    out: list[Mutant] = []
    for name in _SOURCES:
        lines = (src / name).read_text().splitlines()
        for i, line in enumerate(lines, 1):
            if not _code(line):
                continue

            def add(kind: str, new: str, name: str = name, i: int = i,
                    line: str = line) -> None:
                if new != line:
                    out.append(Mutant(name, i, kind, line, new))

            if re.search(r"\b(if|while|for|return)\b", line):
                for m in _CMP.finditer(line):
                    op = m.group(1)
                    flip = {"<": "<=", "<=": "<", ">": ">=", ">=": ">"}[op]
                    add("off-by-one", line[:m.start()] + flip + line[m.end():])
            if bit_re is not None:
                for m in bit_re.finditer(line):
                    add("register bit", line[:m.start()] + f"({m.group(1)} << 1)" +
                        line[m.end():])
            m = _IF.search(line)
            if m and line.count("(") == line.count(")"):
                cond_start = line.index("if (") + 4
                add("dropped check", line[:cond_start] + "0 && (" + line[cond_start:]
                    .replace(m.group(1), m.group(1) + ")", 1))
            for m in _SUB.finditer(line):
                if "->" in m.group(0) or m.group(1) == m.group(2) or \
                        {m.group(1), m.group(2)} & _KEYWORDS:
                    continue
                add("swapped operands", line[:m.start()] + f"{m.group(2)} - {m.group(1)}" +
                    line[m.end():])
            for m in _REL.finditer(line):
                if m.group(1) == m.group(3) or {m.group(1), m.group(3)} & _KEYWORDS:
                    continue
                add("swapped operands", line[:m.start()] +
                    f"{m.group(3)} {m.group(2)} {m.group(1)}" + line[m.end():])
    return out


def pick(candidates: list[Mutant], per_kind: int, seed: int) -> list[Mutant]:
    """A seeded sample of ``per_kind`` faults of each kind, spread over the files."""
    r = random.Random(seed)
    chosen: list[Mutant] = []
    for kind in KINDS:
        pool = [m for m in candidates if m.kind == kind]
        by_file: dict[str, list[Mutant]] = {}
        for m in pool:
            by_file.setdefault(m.file, []).append(m)
        for ms in by_file.values():
            r.shuffle(ms)
        taken: list[Mutant] = []
        while len(taken) < per_kind and any(by_file.values()):
            for f in sorted(by_file):
                if by_file[f] and len(taken) < per_kind:
                    taken.append(by_file[f].pop())
        chosen.extend(sorted(taken, key=lambda m: (m.file, m.line)))
    return chosen


def apply(mutant: Mutant, src: Path = HERE / "src") -> str:
    """The text of ``mutant.file`` with the fault in."""
    lines = (src / mutant.file).read_text().split("\n")
    if lines[mutant.line - 1] != mutant.before:
        raise ValueError(f"{mutant.name}: the source changed since the mutant was made")
    lines[mutant.line - 1] = mutant.after
    return "\n".join(lines)
