"""The pulse journal's cut lines (issue 38 item 4): a line a kill cut, with garbage after it,
is never skipped without a word; what happened to its pulse is decided from the board's pulse
counter where the board kept it (the same boot), else from the order the lines are written in
(``records/journal.py`` ``settle_torn``), and a run that appends after it starts on a line of
its own."""

import json

from snan_hil.records.journal import PulseJournal, read_journal, settle_torn


def _journal(path, pulses, *, base=100, boot=7):
    """A killed run's journal: its start, then ``pulses`` done ones."""
    j = PulseJournal(path, "run-a")
    j.unit = "chip-s0-c1"
    j.baseline(base, boot)
    for i in range(pulses):
        n = j.sent(3, i, "SET", 0.8, 100, "learn")
        j.done(n, 1e-4, 1.1e-4)
    return j


def _cut(path, line, keep):
    """The file ends with the first ``keep`` characters of ``line`` and garbage (no newline)."""
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(line, separators=(",", ":"))[:keep] + "\x00" * 12 + "#!garbage")


def test_a_cut_done_line_is_decided_by_the_boards_pulse_counter(tmp_path):
    path = tmp_path / "pulses.jsonl"
    j = _journal(path, 3)
    n = j.sent(3, 3, "SET", 0.8, 100, "learn")                # the 4th pulse's request went out
    j.close()
    _cut(path, {"r": "run-a", "n": n, "s": "done", "g0": 1e-4, "g1": 2e-4}, 12)
    got = read_journal(path)
    assert got.torn and got.of_run("run-a")[-1].state == "sent"
    # the same boot: the board counted 4 pulses since the run started -> it ran
    told = settle_torn(got, boot=7, counter=104)
    assert len(told) == 1 and "line 9" in told[0] and "says it ran: counted as applied" in told[0]
    assert got.of_run("run-a")[-1].state == "done"
    assert settle_torn(got, boot=7, counter=104) == []       # decided once
    # 3 counted: it did not run
    again = read_journal(path)
    assert "says it did not run" in settle_torn(again, boot=7, counter=103)[0]
    assert again.of_run("run-a")[-1].state == "lost"


def test_without_the_counter_a_cut_reply_line_is_read_or_left_uncertain(tmp_path):
    path = tmp_path / "pulses.jsonl"
    j = _journal(path, 2)
    n = j.sent(3, 2, "RESET", 0.6, 100, "learn")
    j.close()
    _cut(path, {"r": "run-a", "n": n, "s": "done", "g0": 1e-4, "g1": 2e-4}, 30)
    got = read_journal(path)
    told = settle_torn(got, boot=8, counter=500)         # another boot: the counter restarted
    assert "the \"done\" line of pulse 2" in told[0] and "it ran" in told[0]
    assert got.of_run("run-a")[-1].state == "done"
    short = tmp_path / "short.jsonl"
    j = _journal(short, 1)
    n = j.sent(0, 5, "SET", 0.8, 100, "learn")
    j.close()
    _cut(short, {"r": "run-a", "n": n, "s": "done"}, 10)     # cut before its state
    got = read_journal(short)
    told = settle_torn(got)                                 # the legacy protocol: no counter
    assert "counted uncertain, never sent again" in told[0]
    assert got.of_run("run-a")[-1].state == "sent"


def test_a_cut_sent_line_never_went_out_and_the_next_run_starts_on_its_own_line(tmp_path):
    path = tmp_path / "pulses.jsonl"
    _journal(path, 2).close()
    _cut(path, {"r": "run-a", "n": 2, "s": "sent", "u": "chip-s0-c1", "c": [3, 2]}, 25)
    nxt = PulseJournal(path, "run-b")
    nxt.baseline(102, 7)                     # the board counted the 2 done pulses only
    nxt.close()
    got = read_journal(path)
    assert len(got.torn) == 1 and got.baselines["run-b"] == 102    # its line is whole
    told = settle_torn(got)
    assert len(told) == 1
    assert "never went out" in told[0] and "the board's pulse counter agrees" in told[0]
    assert [p.state for p in got.pulses] == ["done", "done"]
