"""The paper's claims and their tests, as data: what `demo`, `compare`, `experiment` and `learn`
say at their end, one line per claim they test (issue 35 point 5; the printer is
:mod:`snan_hil.tools.verdicts`).

A command's result becomes **measures** (:func:`measures`): named numbers of ours, each with
its 95 % interval and the paper's value where the paper states one, keyed like the readings
sweep's conditions (``10x10/astro/median_steps``, ``hw6x6/hw_astro/median_steps``,
``maze40/astro/success_rate``, ``route10/cycle20/median_steps``, ``learn/chip/cycle20/...``).
The paper's values come with the results (each defined once: the comparison's
``PAPER_RESULTS``, the figures' ``PAPER`` tables, ``hil.config.PAPER_MEDIANS``, fig7's
``PAPER``), never from here. A **claim** (:data:`CLAIMS`) names the measures it needs and one
of four tests; it is judged only where a result gives all of them.

Tests (95 % intervals: Wilson for rates, bootstrap for medians, as the results carry them):

* ``match`` — one number: the paper's value *matches* ours when it lies inside our interval
  or within the project's tolerance of our value (success ±7 points, median ±25 % of the
  paper's: :data:`SUCCESS_TOLERANCE`, :data:`MEDIAN_TOLERANCE`, the tolerance the demo's
  table has always used);
* ``effect`` — a change from ``a`` to ``b`` in the paper's direction (``down``: shorter
  routes, ``up``: more success). It is *shown* when b's interval lies wholly beyond a's in
  that direction. **reproduced**: shown and both paper values match; **direction reproduced,
  not the size**: shown, a paper value does not match; **not reproduced**: not shown;
* ``range`` — the paper states one range for every condition of a family (mazes at every
  wall density): **reproduced** when every condition matches the range (its interval meets
  it, or its value lies within the tolerance of it), else **not reproduced** with the count;
* ``equal`` — ``b`` keeps ``a`` within ``±margin`` (hardware keeps the software median).
  The ratio's interval from the two intervals, ``[b_lo / a_hi, b_hi / a_lo]`` (conservative:
  the paired interval would be narrower), inside ``[1 - margin, 1 + margin]``:
  **reproduced**; wholly outside: **not reproduced**; else **undecided** (the intervals are
  too wide to tell, which is not equivalence).
"""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Measure", "Claim", "Verdict", "CLAIMS", "SUCCESS_TOLERANCE", "MEDIAN_TOLERANCE",
           "measures", "judge", "verdicts", "COMMANDS"]

#: the project's tolerance of a success rate (fraction) and of a median (relative)
SUCCESS_TOLERANCE = 0.07
MEDIAN_TOLERANCE = 0.25

REPRODUCED = "reproduced"
DIRECTION_ONLY = "direction reproduced, not the size"
NOT_REPRODUCED = "not reproduced"
UNDECIDED = "undecided"
#: a claim's paper text where the paper gives no number for the task (6x6 route learning)
NO_NUMBER = "–"


@dataclass(frozen=True)
class Measure:
    """One number of ours: ``value`` (a rate as a fraction, or a median in steps; None when
    no trial succeeded), its 95 % interval ``ci`` ([low, high] or None), ``quantity``
    (``success_rate`` | ``median_steps``) and the paper's value (a number, a [low, high]
    range, or None where the paper states none)."""

    value: float | None
    ci: tuple[float, float] | None
    quantity: str
    paper: float | tuple[float, float] | None = None

    def text(self) -> str:
        """``47.3 % [46.0, 48.7]`` / ``153 [138, 167]`` / ``– (no success)``."""
        if self.value is None:
            return "– (no success)"
        rate = self.quantity == "success_rate"
        ci = "" if self.ci is None else " [" + ", ".join(_num(v, rate) for v in self.ci) + "]"
        return f"{_num(self.value, rate)}{' %' if rate else ''}{ci}"


def _num(v: float, rate: bool) -> str:
    if rate:
        return f"{100 * float(v):.1f}"
    return f"{float(v):.0f}" if float(v).is_integer() else f"{float(v):.1f}"


def paper_text(paper: float | Sequence[float] | None, quantity: str) -> str:
    """The paper's value as a line shows it (``46.2 %``, ``97.0–100 %``, ``362``)."""
    if paper is None:
        return "–"
    vals = [paper] if isinstance(paper, (int, float)) else list(dict.fromkeys(paper))
    rate = quantity == "success_rate"
    return "–".join(_num(v, rate) for v in vals) + (" %" if rate else "")


def matches(m: Measure, paper: float | Sequence[float] | None = None) -> bool | None:
    """Whether the paper's value (``paper``, default ``m.paper``) matches ``m`` (module doc:
    inside the interval or within the tolerance); None without a paper value or a value."""
    p = m.paper if paper is None else paper
    if p is None or m.value is None:
        return None
    lo, hi = (float(p), float(p)) if isinstance(p, (int, float)) else (float(p[0]), float(p[1]))
    if m.ci is not None and lo <= m.ci[1] and m.ci[0] <= hi:
        return True
    v = float(m.value)
    gap = 0.0 if lo <= v <= hi else min(abs(v - lo), abs(v - hi))
    if m.quantity == "success_rate":
        return gap <= SUCCESS_TOLERANCE + 1e-12
    ref = lo if v < lo else hi
    return gap <= MEDIAN_TOLERANCE * ref + 1e-12


@dataclass(frozen=True)
class Claim:
    """One claim of the paper and its test (module doc). ``keys``: the measures it compares
    (``effect``/``equal``: ``(a, b)``; ``match``: ``(key,)``; ``range``: ``(pattern,)``, an
    :mod:`fnmatch` pattern over measure keys, every match must hold the paper's range, which
    the measures carry); ``what``: the short name of the numbers (``10x10 median``);
    ``direction``: ``down`` | ``up`` (``effect``); ``margin`` (``equal``)."""

    id: str
    text: str
    source: str
    test: str
    keys: tuple[str, ...]
    what: str
    direction: str = ""
    margin: float = 0.0


@dataclass(frozen=True)
class Verdict:
    """A judged claim: ``verdict`` (reproduced / direction reproduced, not the size / not
    reproduced / undecided), the paper's and our numbers as text, and a note (why)."""

    claim: Claim
    verdict: str
    paper: str
    ours: str
    note: str = ""

    @property
    def reproduced(self) -> bool:
        return self.verdict == REPRODUCED

    def head(self) -> str:
        """The line up to its verdict: ``astrocytes shorten the route (Fig. 4B): 10x10 median
        362 -> 55 in the paper; ours 153 [138, 167] -> 81 [78, 84]``."""
        paper = (f"{self.claim.what} {self.paper} in the paper" if self.paper != NO_NUMBER
                 else f"{self.claim.what}: no number in the paper for this task")
        return f"{self.claim.text} ({self.claim.source}): {paper}; ours {self.ours}"

    def line(self) -> str:
        """:meth:`head`, then ``: <verdict> (<note>)``."""
        note = f" ({self.note})" if self.note else ""
        return f"{self.head()}: {self.verdict}{note}"

    def to_dict(self) -> dict[str, Any]:
        return {"claim": self.claim.id, "text": self.claim.text, "source": self.claim.source,
                "verdict": self.verdict, "paper": self.paper, "ours": self.ours,
                "note": self.note, "line": self.line()}


def _c(id: str, text: str, source: str, test: str, keys: tuple[str, ...], what: str,
       **kw: Any) -> Claim:
    return Claim(id, text, source, test, keys, what, **kw)


def _claims() -> list[Claim]:
    out = []
    for grid, fig in (("3x3", "Fig. 3, section 3.1"), ("10x10", "Fig. 4B, section 3.2")):
        out.append(_c(f"astro-route-{grid}", "astrocytes shorten the route", fig, "effect",
                      (f"{grid}/no_astro/median_steps", f"{grid}/astro/median_steps"),
                      f"{grid} median", direction="down"))
        out.append(_c(f"astro-success-{grid}", "astrocytes raise the success rate", fig,
                      "effect", (f"{grid}/no_astro/success_rate", f"{grid}/astro/success_rate"),
                      f"{grid} success", direction="up"))
    out += [
        _c("maze-astro", "with astrocytes mazes succeed at every wall density",
           "Fig. 5C, section 3.3", "range", ("maze*/astro/success_rate",),
           "success at each density"),
        _c("maze-no-astro", "without astrocytes mazes mostly fail", "Fig. 5C, section 3.3",
           "range", ("maze*/no_astro/success_rate",), "success at each density"),
        _c("maze-median-40", "the maze route at 40 % walls", "Fig. 5B, section 3.3",
           "match", ("maze40/astro/median_steps",), "median at 40 % walls"),
        _c("goals-astro", "three goals: astrocytes succeed at every density",
           "Fig. 6B, section 3.4", "range", ("goals*/astro/success_rate",),
           "success at each density"),
        _c("goals-no-astro", "three goals: without astrocytes the agent fails",
           "Fig. 6B, section 3.4", "range", ("goals*/no_astro/success_rate",),
           "success at each density"),
        _c("return-no-astro", "three goals and back to the start: without astrocytes never",
           "Fig. 6C/D, section 3.4", "range", ("return*/no_astro/success_rate",),
           "success at each density"),
    ]
    for size in (3, 5, 10):
        g = f"route{size}"
        out.append(_c(f"route-{size}", "STDP route learning shortens the test route",
                      "Fig. 7a, section 3.5", "effect",
                      (f"{g}/cycle0/median_steps", f"{g}/cycle20/median_steps"),
                      f"{size}x{size} median (cycle 0 -> 20)", direction="down"))
        out.append(_c(f"route-success-{size}", "route learning raises the success rate",
                      "Fig. 7b, section 3.5", "effect",
                      (f"{g}/cycle0/success_rate", f"{g}/cycle20/success_rate"),
                      f"{size}x{size} success (cycle 0 -> 20)", direction="up"))
    for impl, name in (("sw", "in software"), ("hw", "on the crossbar")):
        out.append(_c(f"hw-astro-{impl}", f"astrocytes halve the 6x6 route {name}",
                      "Fig. 10C, 'Hardware implementation'", "effect",
                      (f"hw6x6/{impl}_noastro/median_steps", f"hw6x6/{impl}_astro/median_steps"),
                      "6x6 median", direction="down"))
    for astro, name in (("noastro", "without"), ("astro", "with")):
        out.append(_c(f"hw-keeps-{astro}", f"the crossbar keeps the software median ({name} "
                      "astrocytes)", "Fig. 10C, 'Hardware implementation'", "equal",
                      (f"hw6x6/sw_{astro}/median_steps", f"hw6x6/hw_{astro}/median_steps"),
                      "6x6 median (software = crossbar)", margin=0.20))
    # the 10x10 field over a chip group (issue 35): the paper's 10x10 numbers are Fig. 4B's
    # (software, fresh weights, random tasks); the hardware claim is Fig. 10C's, carried over
    for impl, name in (("sw", "in software"), ("hw", "on the chip group")):
        out.append(_c(f"hw10-astro-{impl}", f"astrocytes shorten the 10x10 route {name}",
                      "Fig. 4B, section 3.2 (trained route weights here)", "effect",
                      (f"hw10x10/{impl}_noastro/median_steps",
                       f"hw10x10/{impl}_astro/median_steps"),
                      "10x10 median", direction="down"))
    for astro, name in (("noastro", "without"), ("astro", "with")):
        out.append(_c(f"hw10-keeps-{astro}", f"the chip group keeps the software 10x10 median "
                      f"({name} astrocytes)", "Fig. 10C's claim on the 10x10 field", "equal",
                      (f"hw10x10/sw_{astro}/median_steps", f"hw10x10/hw_{astro}/median_steps"),
                      "10x10 median (software = crossbar)", margin=0.20))
    for arm, name in (("software", "in software"), ("device", "on the fitted device model"),
                      ("chip", "on the chip")):
        out.append(_c(f"learn-{arm}", f"route learning shortens the test route {name}",
                      "Fig. 7a, section 3.5", "effect",
                      (f"learn/{arm}/first/median_steps", f"learn/{arm}/last/median_steps"),
                      "median (first -> last cycle)", direction="down"))
        out.append(_c(f"learn-success-{arm}", f"route learning raises the success rate {name}",
                      "Fig. 7b, section 3.5", "effect",
                      (f"learn/{arm}/first/success_rate", f"learn/{arm}/last/success_rate"),
                      "success (first -> last cycle)", direction="up"))
    out.append(_c("learn-chip-keeps", "learning on the chip keeps the software result",
                  "Conclusions, 'equivalent task performance'", "equal",
                  ("learn/software/last/median_steps", "learn/chip/last/median_steps"),
                  "median at the last cycle (software = chip)", margin=0.25))
    return out


#: every claim a command can test, in the order the lines are printed
CLAIMS: tuple[Claim, ...] = tuple(_claims())


# ---- measures of a command's result -------------------------------------------------------
def _ci(v: Any) -> tuple[float, float] | None:
    return None if v is None else (float(v[0]), float(v[1]))


def _m(value: Any, ci: Any, quantity: str, paper: Any = None) -> Measure:
    p = paper if paper is None or isinstance(paper, (int, float)) else tuple(paper)
    return Measure(None if value is None else float(value), _ci(ci), quantity, p)


def _software_rows(rows: Sequence[Mapping[str, Any]]) -> dict[str, Measure]:
    out = {}
    for r in rows:
        cond = f"{r['grid']}/{'astro' if r['astro'] else 'no_astro'}"
        out[f"{cond}/success_rate"] = _m(r["success_rate"], r.get("success_rate_ci"),
                                         "success_rate", r.get("paper_success_rate"))
        out[f"{cond}/median_steps"] = _m(r["median_steps"], r.get("median_steps_ci"),
                                         "median_steps", r.get("paper_median_steps"))
    return out


def _scenarios(scen: Mapping[str, Mapping[str, Any]], field: str = "6x6"
               ) -> dict[str, Measure]:
    out = {}
    for s, v in scen.items():
        out[f"hw{field}/{s}/median_steps"] = _m(v.get("median_steps"),
                                                v.get("median_steps_ci"), "median_steps",
                                                v.get("paper_median_steps"))
        out[f"hw{field}/{s}/success_rate"] = _m(v.get("success_rate"),
                                                v.get("success_rate_ci"), "success_rate")
    return out


def _field(result: Mapping[str, Any]) -> str:
    """``RxC`` of a comparison's field (its config's model grid; 6x6 when not recorded)."""
    grid = (((result.get("config") or {}).get("model") or {}).get("grid") or {})
    return f"{grid.get('rows', 6)}x{grid.get('cols', 6)}"


def _demo(result: Mapping[str, Any]) -> dict[str, Measure]:
    out = _software_rows(result.get("software_vs_paper") or [])
    hil = result.get("hil") or {}
    out.update(_scenarios(hil.get("scenarios") or {}))
    return out


def _compare(result: Mapping[str, Any]) -> dict[str, Measure]:
    return _scenarios(result.get("scenarios") or {}, _field(result))


def _figure_rows(name: str, data: Mapping[str, Any]) -> dict[str, Measure]:
    from snan_hil.host.experiments import fig3, fig4, fig5, fig6, fig7
    rows = data.get("rows") or []
    out: dict[str, Measure] = {}
    if name in ("fig3", "fig4"):
        grid, paper = ("3x3", fig3.PAPER) if name == "fig3" else ("10x10", fig4.PAPER)
        for r in rows:
            if r.get("part") != "main" or r.get("rule", "additive") != "additive":
                continue
            on = bool(r["astro"])
            cond = f"{grid}/{'astro' if on else 'no_astro'}"
            out[f"{cond}/success_rate"] = _m(r["success_rate"], r.get("success_rate_ci"),
                                             "success_rate", paper[on][0])
            out[f"{cond}/median_steps"] = _m(r["median_steps"], r.get("median_steps_ci"),
                                             "median_steps", paper[on][1])
    elif name == "fig5":
        for r in rows:
            on = bool(r["astro"])
            cond = f"maze{round(100 * r['wall_fraction'])}/{'astro' if on else 'no_astro'}"
            out[f"{cond}/success_rate"] = _m(r["success_rate"], r.get("success_rate_ci"),
                                             "success_rate", fig5.PAPER_SUCCESS[on])
            out[f"{cond}/median_steps"] = _m(r["median_steps"], r.get("median_steps_ci"),
                                             "median_steps", r.get("paper_median_steps"))
    elif name == "fig6":
        fail = fig6.PAPER_FAILURE_NO_ASTRO
        for r in rows:
            if r.get("part") == "return" and not r["astro"]:
                out[f"return{round(100 * r['wall_fraction'])}/no_astro/success_rate"] = _m(
                    r["success_rate"], r.get("success_rate_ci"), "success_rate",
                    fig6.PAPER_RETURN_NO_ASTRO)
            if r.get("part") != "multi":
                continue
            on = bool(r["astro"])
            span = fig6.PAPER_SUCCESS_ASTRO if on else (1.0 - fail[1], 1.0 - fail[0])
            cond = f"goals{round(100 * r['wall_fraction'])}/{'astro' if on else 'no_astro'}"
            out[f"{cond}/success_rate"] = _m(r["success_rate"], r.get("success_rate_ci"),
                                             "success_rate", span)
    elif name == "fig7":
        main = rows[0].get("variant") if rows else None
        last = max((r["cycle"] for r in rows if r.get("variant") == main), default=0)
        for r in rows:
            size = int(str(r["grid"]).split("x")[0])
            if r.get("variant") != main or r["cycle"] not in (0, last) or size not in fig7.PAPER:
                continue
            p = fig7.PAPER[size]
            c = "cycle0" if r["cycle"] == 0 else "cycle20"
            first = r["cycle"] == 0
            out[f"route{size}/{c}/median_steps"] = _m(
                r.get("test_median_steps"), r.get("test_median_steps_ci"), "median_steps",
                p[0] if first else p[1])
            out[f"route{size}/{c}/success_rate"] = _m(
                r.get("test_success_rate"), r.get("test_success_rate_ci"), "success_rate",
                p[2] if first else p[3])
    return out


def _experiment(result: Mapping[str, Any]) -> dict[str, Measure]:
    out: dict[str, Measure] = {}
    for name, data in (result.get("figures") or {}).items():
        out.update(_figure_rows(name, data))
    return out


def _learn(result: Mapping[str, Any]) -> dict[str, Measure]:
    out: dict[str, Measure] = {}
    paper = result.get("paper") or {}
    pm, ps = paper.get("median") or {}, paper.get("success") or {}
    for arm, a in (result.get("arms") or {}).items():
        c = a.get("curves") or {}
        if not c.get("median"):
            continue
        last = len(c["median"]) - 1
        for tag, k in (("first", 0), ("last", last)):
            out[f"learn/{arm}/{tag}/median_steps"] = _m(c["median"][k], c["median_ci"][k],
                                                        "median_steps", pm.get(str(k)))
            out[f"learn/{arm}/{tag}/success_rate"] = _m(c["success"][k], c["success_ci"][k],
                                                        "success_rate", ps.get(str(k)))
    return out


#: how each command's result becomes measures
COMMANDS = {"demo": _demo, "compare": _compare, "experiment": _experiment, "learn": _learn}


def measures(command: str, result: Mapping[str, Any]) -> dict[str, Measure]:
    """The measures of ``command``'s result (``demo``: its summary; ``compare``: the results
    of :func:`~snan_hil.host.hil.compare.run_compare`; ``experiment``: ``{"figures": {name:
    figure data}}``; ``learn``: its results document). Raises KeyError for another
    command."""
    return COMMANDS[command](result)


# ---- the tests ----------------------------------------------------------------------------
def _beyond(a: Measure, b: Measure, direction: str) -> bool:
    if a.ci is None or b.ci is None:
        return False
    return b.ci[1] < a.ci[0] if direction == "down" else b.ci[0] > a.ci[1]


def _outside_note(ms: Sequence[Measure]) -> str:
    bad = [paper_text(m.paper, m.quantity) for m in ms if matches(m) is False]
    if not bad:
        return ""
    return ("the paper's " + " and ".join(bad) + (" lies" if len(bad) == 1 else " lie")
            + " outside our interval" + ("" if len(bad) == 1 else "s") + " and tolerance")


def _effect(c: Claim, a: Measure, b: Measure) -> Verdict:
    paper = (NO_NUMBER if a.paper is None and b.paper is None else
             f"{paper_text(a.paper, a.quantity)} -> {paper_text(b.paper, b.quantity)}")
    ours = f"{a.text()} -> {b.text()}"
    if a.value is None or b.value is None:
        return Verdict(c, NOT_REPRODUCED, paper, ours, "no successful trial to compare")
    if not _beyond(a, b, c.direction):
        return Verdict(c, NOT_REPRODUCED, paper, ours,
                       "the intervals overlap" if a.ci and b.ci and a.ci[0] <= b.ci[1]
                       and b.ci[0] <= a.ci[1] else "the change goes the other way")
    if a.paper is None and b.paper is None:
        return Verdict(c, REPRODUCED, NO_NUMBER, ours, "the direction")
    note = _outside_note([m for m in (a, b) if m.paper is not None])
    return Verdict(c, DIRECTION_ONLY if note else REPRODUCED, paper, ours, note)


def _equal(c: Claim, a: Measure, b: Measure) -> Verdict:
    paper = ("equal" if a.paper is None else
             f"equal ({paper_text(a.paper, a.quantity)} in both)")
    if a.value is None or b.value is None or a.ci is None or b.ci is None or a.ci[0] <= 0:
        return Verdict(c, UNDECIDED, paper, f"{a.text()} vs {b.text()}", "no interval")
    ratio = b.value / a.value - 1.0
    lo, hi = b.ci[0] / a.ci[1], b.ci[1] / a.ci[0]
    ours = f"{a.text()} vs {b.text()} ({100 * ratio:+.0f} %)"
    m = c.margin
    band = f"ratio interval [{lo:.2f}, {hi:.2f}] vs ±{100 * m:.0f} %"
    if 1 - m <= lo and hi <= 1 + m:
        return Verdict(c, REPRODUCED, paper, ours, band)
    if hi < 1 - m or lo > 1 + m:
        return Verdict(c, NOT_REPRODUCED, paper, ours, band)
    return Verdict(c, UNDECIDED, paper, ours,
                   f"{band}: the intervals are too wide to tell; not an equivalence")


def _range(c: Claim, ms: Mapping[str, Measure]) -> Verdict:
    keys = sorted(ms, key=_density)
    first = ms[keys[0]]
    paper = paper_text(first.paper, first.quantity)
    vals = sorted(float(m.value) for m in ms.values() if m.value is not None)
    q = first.quantity
    ours = ("–" if not vals else paper_text(vals[0], q) if vals[0] == vals[-1]
            else f"{_num(vals[0], q == 'success_rate')}–{paper_text(vals[-1], q)}")
    bad = [k for k in keys if not matches(ms[k])]
    if not bad:
        return Verdict(c, REPRODUCED, paper, ours, f"all {len(keys)} densities")
    worst = ", ".join(f"{_density(k)} % walls: {ms[k].text()}" for k in bad[:3])
    more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
    return Verdict(c, NOT_REPRODUCED, paper, ours,
                   f"{len(keys) - len(bad)} of {len(keys)} densities; outside: {worst}{more}")


def _density(key: str) -> int:
    head = key.split("/")[0]
    digits = "".join(ch for ch in head if ch.isdigit())
    return int(digits) if digits else 0


def judge(c: Claim, ms: Mapping[str, Measure]) -> Verdict | None:
    """The verdict of claim ``c`` on the measures ``ms``; None when they lack what it needs."""
    if c.test == "range":
        hit = {k: m for k, m in ms.items() if fnmatch.fnmatchcase(k, c.keys[0])
               and m.paper is not None}
        return _range(c, hit) if hit else None
    if not all(k in ms for k in c.keys):
        return None
    if c.test == "match":
        m = ms[c.keys[0]]
        if m.paper is None:
            return None
        ok = matches(m)
        return Verdict(c, REPRODUCED if ok else NOT_REPRODUCED, paper_text(m.paper, m.quantity),
                       m.text(), "" if ok else _outside_note([m]))
    a, b = ms[c.keys[0]], ms[c.keys[1]]
    if c.test == "effect":
        return _effect(c, a, b)
    if c.test == "equal":
        return _equal(c, a, b)
    raise ValueError(f"claim {c.id}: unknown test {c.test!r}")


def verdicts(command: str, result: Mapping[str, Any]) -> list[Verdict]:
    """One verdict per claim ``command``'s result tests, in :data:`CLAIMS` order."""
    ms = measures(command, result)
    out = [judge(c, ms) for c in CLAIMS]
    return [v for v in out if v is not None]
