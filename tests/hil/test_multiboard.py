"""Several boards in one run (issue 25): ``compare --boards`` spreads the weight sets over
emulated boards held by Dask workers (:mod:`snan_hil.lab.boards`), scheduled by the one loop of
every job over several boards (:mod:`snan_hil.lab.fanout`).

The contract under test: set p of the run goes to board p mod B, each board runs its sets in
order from a fresh boot, so every set's launches are bit-identical to a one-board run of that
board's sets on a chip made alike (fresh, same seed); the report says which board ran which set
and holds every board's snapshot; bad input is one line, exit 2, before any work; a board lost
mid-run keeps the finished sets, and its sets either resume on it (``--resume``) or move
(``reassign``).
"""

import json
import os
import sqlite3
import sys
from pathlib import Path

import cloudpickle
import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.checkpoint import open_run
from snan_hil.host.hil.compare import (CompareJob, CompareRequest, boards_fields, run_software,
                                       without_wall_times)
from snan_hil.host.hil.config import load_hil_config
from snan_hil.lab.boards import LinkOptions, assign, check_ports, local_boards
from snan_hil.lab.fanout import BoardSet, run_group, run_on_boards
from snan_hil.lab.opener import FileUse
from snan_hil.lab.runner import RunOptions
from snan_hil.records.journal import read_journal
from snan_hil.tools import cli

# the module fixtures run whole comparisons over two boards (software arm, programming,
# launches): on 2 cores beside another test worker that can pass the suite's 120 s
pytestmark = pytest.mark.timeout(400)


SHORT = ["--set", "grid.max_steps=15"]


def emu(path):
    return f"emu://?state={path}"


def compare_argv(weights, out, *extra):
    return ["compare", "--weights", str(weights), "--out", str(out), "--launches", "2",
            "--seed", "4", "--json", "--no-figure", *SHORT, *extra]


def results(out):
    return json.loads((Path(out) / "compare.json").read_text())


def launches_of(res, k):
    """Set k's launch rows and summaries, wall times left out."""
    view = without_wall_times(res)
    return ([r for r in view["launch_rows"] if r["set"] == k],
            [r for r in view["per_set"] if r["set"] == k],
            res["programming"][str(k)] | {"wall_s": None})


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("multiboard")
    with pytest.MonkeyPatch.context() as mp:        # the workers inherit it
        mp.setenv("XDG_DATA_HOME", str(d / "xdg"))
        yield d


@pytest.fixture(scope="module")
def lent(data):
    """ONE LocalCluster of two board workers shared by the tests below (each run installs
    its plugin, naming its own chips; the CLI's --dask run uses the workers' own ports,
    fresh chips lent-0/lent-1). allowed_failures=0: a killed worker loses its unit."""
    ports = [emu(data / "lent-0.npz"), emu(data / "lent-1.npz")]
    with local_boards(ports, allowed_failures=0) as client:
        yield client


@pytest.fixture(scope="module")
def two_boards(cli_trained, data):
    """compare over two fresh emulated boards (set 0 on board 0, set 1 on board 1)."""
    ports = f"{emu(data / 'a.npz')},{emu(data / 'b.npz')}"
    assert cli.main(compare_argv(cli_trained, data / "multi", "--boards", ports,
                                 "--sample", "multi-sample")) == 0
    return results(data / "multi")


@pytest.fixture(scope="module")
def one_board(cli_trained, data):
    """compare of each set alone on a fresh chip (the one-board runs of each board's sets),
    and of both sets on one fresh chip."""
    alone = {}
    for k in (0, 1):
        out = data / f"alone-{k}"
        assert cli.main(compare_argv(cli_trained, out, "--port", emu(data / f"r{k}.npz"),
                                     "--weight-set", str(k))) == 0
        alone[k] = results(out)
    assert cli.main(compare_argv(cli_trained, data / "both", "--port",
                                 emu(data / "rboth.npz"))) == 0
    return alone, results(data / "both")


def _sigint_disposition():
    import signal
    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_board_workers_leave_a_ctrl_c_to_the_command(lent):
    """The workers ignore SIGINT (the terminal sends it to the whole process group; each
    worker printed two tracebacks): the command's process handles it alone."""
    assert set(lent.run(_sigint_disposition).values()) == {True}

def test_sets_go_to_boards_by_position():
    assert assign([0, 1, 2, 3, 4], 2) == {0: 0, 1: 1, 2: 0, 3: 1, 4: 0}
    assert assign([5, 2, 7], 3) == {5: 0, 2: 1, 7: 2}
    # no more sets than boards: by position whatever the cost
    assert assign([5, 2, 7], 3, {5: 1.0, 2: 50.0, 7: 9.0}) == {5: 0, 2: 1, 7: 2}


def test_sets_are_balanced_by_their_predicted_board_time():
    """The round-5 bench's six sets (board s: programming + launches, measured): by position
    boards hold 43.5 / 75.7 / 117.2 s; balanced, the largest holds 85.8 s (the best split of
    these six is 78.8 s at most 4/3 below). Boards numbered by their first set's position."""
    cost = {0: 12.8, 1: 42.3, 2: 42.3, 3: 30.7, 4: 33.4, 5: 74.9}
    where = assign(list(cost), 3, cost)
    load = [sum(c for k, c in cost.items() if where[k] == b) for b in range(3)]
    assert max(load) == pytest.approx(85.8)
    # longest first: 5 alone; 1 then 4; 2, 3, 0 — numbered by their first set (0, 1, 5)
    assert where == {0: 0, 2: 0, 3: 0, 1: 1, 4: 1, 5: 2}
    assert assign(list(cost), 3, dict(reversed(cost.items()))) == where   # a pure function
    # the order of the run's sets numbers the boards, not the balance
    assert assign([3, 1, 0, 2], 2, {0: 1.0, 1: 1.0, 2: 5.0, 3: 1.0})[3] == 0


def test_a_sets_predicted_board_time_is_programming_and_its_software_twins_decisions(
        cli_trained):
    """predicted_board_cost: PROGRAMMING_DECISIONS + the steps of the set's launches in the
    software twins of the hardware scenarios, as a software-only compare launches them."""
    from snan_hil.host.hil.compare import PROGRAMMING_DECISIONS, predicted_board_cost
    hil = load_hil_config(None, ["grid.max_steps=15"])
    request = CompareRequest(str(cli_trained), hil, launches=2, seed=4,
                             scenarios=("sw_astro", "hw_astro", "hw_noastro"))
    sw = run_software(CompareJob(CompareRequest(str(cli_trained), hil, launches=2, seed=4,
                                                scenarios=("sw_astro", "sw_noastro"))))
    cost = predicted_board_cost(request)
    assert sorted(cost) == [0, 1]
    for k in (0, 1):
        steps = sum(r["steps"] for r in sw["launch_rows"] if r["set"] == k)
        assert steps > 0 and cost[k] == PROGRAMMING_DECISIONS + steps
    only_astro = predicted_board_cost(CompareRequest(str(cli_trained), hil, launches=2,
                                                     seed=4, scenarios=("hw_astro",),
                                                     program=False))
    assert only_astro[0] == sum(r["steps"] for r in sw["launch_rows"]
                                if r["set"] == 0 and r["scenario"] == "sw_astro")

def test_two_boards_give_the_launches_of_one_board_runs_bit_for_bit(two_boards, one_board):
    alone, _both = one_board
    for k in (0, 1):
        assert launches_of(two_boards, k) == launches_of(alone[k], k)
        assert two_boards["weights"]["fingerprints"][str(k)] == \
            alone[k]["weights"]["fingerprints"][str(k)]
    assert two_boards["sets"] == [0, 1]
    hw = [r for r in two_boards["launch_rows"] if r["scenario"].startswith("hw_")]
    assert hw and all(r["virtual_us"] for r in hw)           # the sets ran on the boards


def test_the_report_says_which_board_ran_each_set_with_every_boards_snapshot(two_boards,
                                                                            data):
    units, boards = two_boards["units"], two_boards["boards"]
    assert [units[k]["board"] for k in ("0", "1")] == [0, 1]
    assert units["0"]["port"] == emu(data / "a.npz") and units["1"]["port"] == \
        emu(data / "b.npz")
    assert units["0"]["board_id"] != units["1"]["board_id"]          # two chips
    assert [b["board"] for b in boards] == [0, 1]
    for b, name in zip(boards, ("a", "b")):
        assert b["session"]["format"] == "snan-hil-session/1"
        assert b["session"]["files"]["layout"] == str(data / f"{name}.layout.json")
        assert (data / f"{name}.layout.json").is_file()              # each board's own
        assert (data / f"{name}.history.sqlite").is_file()
        assert b["lost"] is None
    assert two_boards["session"] == boards[0]["session"]
    assert (data / "multi" / "programming" / "program-set1.json").is_file()


def test_the_run_is_recorded_with_its_metadata_launches_stream_and_boards(two_boards, data):
    """compare --boards is one run (kind hil) in the user's runs database: its metadata,
    the launches stream of every set, the boards in its start and stop; each board's own
    history records its share (kind hil, as a one-board compare records it: its sets'
    programming pulses) with the run's metadata."""
    from snan_hil.records.history import History
    meta = two_boards["run"]
    assert meta["sample"] == "multi-sample" and meta["uid"]
    with History.open(data / "xdg" / "snan-hil" / "runs.history.sqlite", create=False) as db:
        run = db.run(meta["uid"])
        assert run is not None and run.kind == "hil" and run.status == "complete"
        docs = [(n, d) for _i, n, d in db.documents(run.id)]
    start = docs[0][1]
    assert docs[0][0] == "start" and start["sample"] == "multi-sample"
    assert [b["port"] for b in start["config"]["boards"]] == \
        [emu(data / "a.npz"), emu(data / "b.npz")]
    launches = [d["data"] for n, d in docs if n == "event" and "scenario" in d["data"]]
    assert len(launches) == len(two_boards["launch_rows"]) == 2 * 4 * 2
    assert sorted((e["set_index"], e["scenario"], e["launch"]) for e in launches) == sorted(
        (r["set"], r["scenario"], r["launch"]) for r in two_boards["launch_rows"])
    stop = docs[-1][1]
    assert docs[-1][0] == "stop" and stop["exit_status"] == "success"
    for name in ("a", "b"):
        with History.open(data / f"{name}.history.sqlite", create=False) as db:
            runs = db.runs("hil")
            assert {r.sample for r in runs} == {"multi-sample"}
            assert sum(r.pulses for r in runs) > 0


@pytest.mark.parametrize("extra, says", [
    (["--boards", "emu://?state=X,emu://?state=X"], "same board"),
    (["--boards", "emu://?state=X"], "needs two ports"),
    (["--boards", "emu://?state=X,,emu://?state=Y"], "entry 2 of"),
    (["--boards", "emu://?state=X,emu://?state=Y", "--dask", "tcp://127.0.0.1:1"],
     "not both"),
    (["--boards", "emu://?state=X,emu://?state=Y", "--port", "emu"], "--port"),
    (["--boards", "emu://?state=X,emu://?state=Y", "--scenarios", "sw_noastro"],
     "hardware"),
    (["--reassign"], "--boards or --dask"),
])
def test_bad_board_options_are_one_line_and_exit_2_before_any_work(cli_trained, tmp_path,
                                                                   capsys, extra, says):
    extra = [e.replace("X", str(tmp_path / "x.npz")).replace("Y", str(tmp_path / "y.npz"))
             for e in extra]
    assert cli.main(compare_argv(cli_trained, tmp_path / "out", *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "out").exists()
    assert not (tmp_path / "x.npz").exists() and not (tmp_path / "y.npz").exists()


def test_an_unreachable_scheduler_is_one_line_and_exit_2(cli_trained, tmp_path, capsys):
    assert cli.main(compare_argv(cli_trained, tmp_path / "out",
                                 "--dask", "tcp://127.0.0.1:9")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach the Dask scheduler" in err[0], err
    assert not (tmp_path / "out" / "compare.json").exists()


def test_check_ports_counts_one_chip_reached_twice_as_one_board(tmp_path):
    with pytest.raises(UserError, match="same board"):
        check_ports([emu(tmp_path / "c.npz"), emu(tmp_path / "sub" / ".." / "c.npz")],
                    LinkOptions())
    assert check_ports([emu(tmp_path / "c.npz"), emu(tmp_path / "d.npz")], LinkOptions()) == \
        [emu(tmp_path / "c.npz"), emu(tmp_path / "d.npz")]


# -- a board lost mid-run -------------------------------------------------------------------

def dying_board_1(job, task, after=None):
    """The group's task, except that the worker holding board 1 dies inside its set (after
    the chip was saved at the set's start, before the set's results): a board lost
    mid-run."""
    import snan_hil.host.hil.compare as compare
    import snan_hil.lab.boards as boards
    if boards._plugin().index == 1:
        def die(*args, **kwargs):
            os._exit(3)
        compare.CompareJob.set_record = die     # this worker process ends here
    return run_group(job, task, after)


def mistaken_board_1(job, task, after=None):
    """The group's task, except that board 1's set stops on a user mistake (as a config the
    board's limits refuse would)."""
    import snan_hil.lab.boards as boards
    if boards._plugin().index == 1:
        raise UserError("max_write_v 9 V is above the board's limit 5 V; lower it")
    return run_group(job, task, after)


cloudpickle.register_pickle_by_value(sys.modules[__name__])


def _compare(client, weights, ports, out, *, resume, task=run_group, reassign=False,
             link=None, stop_requested=None):
    """The comparison over the shared cluster's two workers, holding the chips ``ports``
    (lab.fanout.run_on_boards, as compare --boards runs it)."""
    hil = load_hil_config(None, ["grid.max_steps=15"])
    job = CompareJob(CompareRequest(str(weights), hil, launches=2, seed=4,
                                    report_dir=Path(out) / "programming"))
    folder = open_run(out, "compare", {"test": "lost board"}, resume=resume)
    job.start_here(folder.resumed)
    client.wait_for_workers(2)                  # a killed worker is back (its nanny)
    boards = BoardSet(tuple(ports), None, LinkOptions(), FileUse(updates_layout=True),
                      reassign=reassign)
    done = run_on_boards(job, boards, RunOptions(record="off", folder=folder), link=link,
                         stop_requested=stop_requested, task=task, client=client)
    return boards_fields(job, done.result, done.units, done.boards)


def test_a_lost_board_keeps_the_finished_sets_and_resumes_to_identical_results(
        cli_trained, two_boards, lent, tmp_path):
    ports = [emu(tmp_path / "c.npz"), emu(tmp_path / "d.npz")]
    out = tmp_path / "out"
    with pytest.raises(UserError, match=r"board 1 .* was lost .*--resume"):
        _compare(lent, cli_trained, ports, out, resume=False, task=dying_board_1)
    done = sorted(p.name for p in (out / "checkpoint").glob("unit-set-*.json"))
    assert done == ["unit-set-0.json"]                          # board 0's set kept
    res = _compare(lent, cli_trained, ports, out, resume=True)
    assert res["resumed"] is True
    for k in (0, 1):
        a, b = launches_of(res, k), launches_of(two_boards, k)
        for x, y in zip(a[0], b[0]):
            assert {kk: v for kk, v in x.items() if v != y[kk]} == {}, (k, x, y)
        assert a == b
    assert [res["units"][k]["board"] for k in ("0", "1")] == [0, 1]


def test_a_stop_from_watch_ends_every_board_before_its_next_request_and_resumes(
        cli_trained, two_boards, lent, tmp_path):
    """A stop in the run's control channel (as snan-hil watch writes it): each board's
    worker sees it before its next board request (UnitStopped), the run raises StopRequested
    (exit 130 in the CLI) with nothing committed half; --resume without the stop gives the
    launches of an uninterrupted run."""
    from snan_hil.lab.boards import RunLink
    from snan_hil.records.control import RunControl, StopRequested
    from snan_hil.records.history import History
    db = tmp_path / "runs.sqlite"
    with History.open(db) as h:
        h.request_control("run-1", "stop", "test")
    ports = [emu(tmp_path / "s0.npz"), emu(tmp_path / "s1.npz")]
    out = tmp_path / "out"
    host = RunControl(db, "run-1")
    with pytest.raises(StopRequested):
        _compare(lent, cli_trained, ports, out, resume=False,
                 link=RunLink(history=str(db), uid="run-1", metadata={"sample": "S"}),
                 stop_requested=host.stop_requested)
    host.close()
    assert host.stop_requested()
    assert not list((out / "checkpoint").glob("unit-set-*.json"))     # no set finished
    res = _compare(lent, cli_trained, ports, out, resume=True,
                   link=RunLink(history=str(db), uid="run-2"))
    for k in (0, 1):
        assert launches_of(res, k) == launches_of(two_boards, k)

def test_reassign_moves_a_lost_boards_set_to_another_board(cli_trained, one_board, lent,
                                                           tmp_path):
    _alone, both = one_board
    ports = [emu(tmp_path / "e.npz"), emu(tmp_path / "f.npz")]
    res = _compare(lent, cli_trained, ports, tmp_path / "out", resume=False,
                   task=dying_board_1, reassign=True)
    assert [res["units"][k]["board"] for k in ("0", "1")] == [0, 0]
    lost = [b for b in res["boards"] if b["lost"]]
    assert [b["board"] for b in lost] == [1]
    # board 0 ran set 0 then set 1 (reprogrammed over set 0): a one-board run of both sets
    for k in (0, 1):
        assert launches_of(res, k) == launches_of(both, k)



def test_a_user_mistake_in_a_unit_is_one_line_and_the_board_is_not_lost(cli_trained, lent,
                                                                       tmp_path):
    ports = [emu(tmp_path / "g.npz"), emu(tmp_path / "h.npz")]
    with pytest.raises(UserError) as caught:
        _compare(lent, cli_trained, ports, tmp_path / "out", resume=False,
                 task=mistaken_board_1, reassign=True)
    text = str(caught.value)
    assert text.startswith("set 1 on board 1: max_write_v 9 V") and "\n" not in text
    assert "lost" not in text                   # not a board failure, not reassigned


# -- a scheduler's workers: --dask ------------------------------------------------------------

def test_dask_scheduler_workers_run_the_sets_as_the_boards_option_does(cli_trained, lent,
                                                                       two_boards, data):
    """The shared cluster's workers hold fresh chips (lent-0, lent-1) made as a.npz, b.npz:
    the launches are those of the --boards run; each board's chip saved before each set (so a
    rerun set starts from it: the lost-board tests) is dropped once the set is committed."""
    address = lent.scheduler.address
    out = data / "dask"
    assert cli.main(compare_argv(cli_trained, out, "--dask", address)) == 0
    res = results(out)
    for k in (0, 1):
        assert launches_of(res, k) == launches_of(two_boards, k)
    assert [res["units"][k]["port"] for k in ("0", "1")] == \
        [emu(data / "lent-0.npz"), emu(data / "lent-1.npz")]
    assert sorted(p.name for p in (out / "checkpoint").glob("unit-set-*.json")) == \
        ["unit-set-0.json", "unit-set-1.json"]
    assert not list((out / "checkpoint").glob("boundaries/**/saved"))


# -- lab-bench batch jobs: the same job on every board's chip -------------------------------

def test_a_plan_on_several_boards_runs_on_each_chip_as_on_one_board(data, capsys):
    """plan run --boards: each board's chip runs the plan, its own -o file and history run;
    the cells' results are those of a one-board run on a chip made alike."""
    ports = [emu(data / "pa.npz"), emu(data / "pb.npz")]
    assert cli.main(["plan", "run", "switching-sweep-set", "--cells", "0,0", "--boards",
                     ",".join(ports), "-o", str(data / "plan.json")]) == 0
    err = capsys.readouterr().err
    assert f"board 0 ({ports[0]}" in err and f"board 1 ({ports[1]}" in err
    assert cli.main(["plan", "run", "switching-sweep-set", "--cells", "0,0", "--port",
                     emu(data / "pone.npz"), "-o", str(data / "plan-one.json")]) == 0
    one = json.loads((data / "plan-one.json").read_text())
    for b, name in ((0, "pa"), (1, "pb")):
        res = json.loads((data / f"plan.board-{b}.json").read_text())
        assert res["board"]["port"] == ports[b]
        assert res["cells"] == one["cells"]
        with sqlite3.connect(data / f"{name}.history.sqlite") as db:
            kinds = [r[0] for r in db.execute("select kind from runs")]
        assert kinds == ["plan"]                    # the board's own history holds its run
    assert not (data / "plan.json").exists()


def test_a_cell_test_on_several_boards_writes_each_boards_own_report_as_on_one_board(
        data, capsys):
    """cells test --boards: the job replicated on each board's chip; each board's -o and
    --good-csv are its own (.board-<i>, written on the host from the board's result, with
    its port and identity), the classes those of a one-board run on a chip made alike."""
    argv = ["cells", "test", "--cells", "0,0", "1,2", "--ratio-above", "2"]
    ports = [emu(data / "ct-a.npz"), emu(data / "ct-b.npz")]
    assert cli.main([*argv, "--boards", ",".join(ports), "-o", str(data / "ct.json"),
                     "--good-csv", str(data / "ctg.csv")]) == 0
    err = capsys.readouterr().err
    assert f"board 0 ({ports[0]}" in err and f"board 1 ({ports[1]}" in err
    assert cli.main([*argv, "--port", emu(data / "ct-one.npz"), "-o",
                     str(data / "ct-one.json")]) == 0
    one = json.loads((data / "ct-one.json").read_text())
    for b in (0, 1):
        res = json.loads((data / f"ct.board-{b}.json").read_text())
        assert res["cells"] == one["cells"] and res["summary"] == one["summary"]
        assert res["board"]["port"] == res["session"]["port"] == ports[b]
        assert res["board"]["board_id"] == res["session"]["identity"]["board_id"]
        assert res["run"]["history_run_id"] == 1          # the board's own history's run
        assert (data / f"ctg.board-{b}.csv").read_text().startswith("row,col,verdict")
    assert not (data / "ct.json").exists() and not (data / "ctg.csv").exists()


def test_a_user_mistake_in_a_board_job_is_one_line_and_exit_2(lent, capsys):
    """cells test --dask on the shared cluster's boards, with a cell off the crossbar."""
    assert cli.main(["cells", "test", "--cells", "40,0", "--dask",
                     lent.scheduler.address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("snan-hil cells: error: board 0 ("), err


# -- learn: one learning session per unit ----------------------------------------------------

LEARN = ["learn", "--json", "--cycles", "1", "--set", "grid.max_steps=15"]
"""learn's options here; --sessions (2) and --arms (chip) are given by each test, once."""
TWO_CHIP = ["--sessions", "2", "--arms", "chip"]


@pytest.fixture(scope="module")
def device_model(data):
    path = data / "model.json"
    assert cli.main(["characterize", "--port", emu(data / "char.npz"), "--cells",
                     "0,0;0,1;1,2;2,3;3,4;4,5", "--repeats", "1", "--json", "--model",
                     str(path)]) == 0
    return path


def test_learn_sessions_run_on_their_boards_as_on_one_board(data, device_model, capsys):
    """learn --boards: session k on board k mod 2, each on its own fresh chip; session 0 is
    that of a one-board run of one session on a chip made alike; each board's history holds
    its own learn run; the ledger's rows name the board."""
    ports = [emu(data / "la.npz"), emu(data / "lb.npz")]
    assert cli.main([*LEARN, *TWO_CHIP, "--model", str(device_model), "--boards",
                     ",".join(ports), "--out", str(data / "learn-multi")]) == 0
    assert cli.main([*LEARN, "--sessions", "1", "--arms", "chip", "--model", str(device_model),
                     "--port", emu(data / "lone.npz"), "--out", str(data / "learn-one")]) == 0
    capsys.readouterr()
    multi = json.loads((data / "learn-multi" / "learn.json").read_text())
    one = json.loads((data / "learn-one" / "learn.json").read_text())
    assert multi["arms"]["chip"]["sessions"][0] == one["arms"]["chip"]["sessions"][0]
    assert [multi["units"][k]["port"] for k in ("0", "1")] == ports
    assert {(r["session"], r["board"]) for r in multi["ledger"]["rows"]} == {(0, 0), (1, 1)}
    for name in ("la", "lb"):
        with sqlite3.connect(data / f"{name}.history.sqlite") as db:
            assert "learn" in [r[0] for r in db.execute("select kind from runs")]


@pytest.mark.parametrize("extra, says", [
    (["--boards", "emu://?state=X,emu://?state=Y"], "--model FILE"),
    (["--boards", "emu://?state=X,emu://?state=Y", "--arms", "software"], "no chip"),
    (["--boards", "emu://?state=X,emu://?state=Y", "--port", "emu"], "--port"),
    (["--reassign"], "--boards or --dask"),
])
def test_bad_learn_board_options_are_one_line_and_exit_2(tmp_path, capsys, extra, says):
    extra = [e.replace("X", str(tmp_path / "x.npz")).replace("Y", str(tmp_path / "y.npz"))
             for e in extra]
    own = [] if "--arms" in extra else ["--arms", "chip"]             # an option once
    assert cli.main([*LEARN, "--sessions", "2", *own, "--out", str(tmp_path / "out"),
                     *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "out").exists() and not (tmp_path / "x.npz").exists()


def test_learn_dask_checks_the_scheduler_before_any_arm_runs(device_model, tmp_path, capsys,
                                                            monkeypatch):
    """Issue 38 item 8: a scheduler that does not answer is one line at once, before the
    software and device arms run (they ran first, then the line came)."""
    import socket

    import snan_hil.host.hil.learn as learn

    def no_arm(*_a, **_k):
        raise AssertionError("an arm ran before the scheduler was reached")
    monkeypatch.setattr(learn, "software_session", no_arm)
    monkeypatch.setattr(learn, "device_session", no_arm)
    with socket.socket() as s:                  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    assert cli.main([*LEARN, "--arms", "software,device,chip", "--model", str(device_model),
                     "--dask", f"tcp://127.0.0.1:{port}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach the Dask scheduler" in err[0], err
    assert not out.exists()                     # nothing ran, nothing left


# -- learn: a board lost mid-session -----------------------------------------------------------

def dying_learner_1(job, task, after=None):
    """The group's task, except that the worker holding board 1 dies right after the first
    cycle of its session that applied pulses (its journal marks them done, its history has
    them, the cycle is not committed): a board lost mid-session."""
    import snan_hil.host.hil.learn_chip as learn_chip
    import snan_hil.lab.boards as boards
    if boards._plugin().index == 1:
        apply = learn_chip.CyclePulses.apply

        def apply_then_die(self, orders, replay):
            events = apply(self, orders, replay)
            if events:
                self.bench.observer.flush()     # what the history buffered, then the end
                os._exit(3)
            return events
        learn_chip.CyclePulses.apply = apply_then_die
    return run_group(job, task, after)


def _learn(client, model_path, ports, out, *, resume=False, task=run_group, reassign=False):
    """learn's chip arm (2 sessions x 2 cycles) over the shared cluster's two workers,
    holding the chips ``ports``, each session's pulses recorded in its board's history
    (lab.fanout.run_on_boards, as learn --boards runs it)."""
    from snan_hil.crossbar_model.fitted import DeviceModel
    from snan_hil.host.hil.learn import LearnConfig, LearnJob, board_units
    hil = load_hil_config(None, ["grid.max_steps=15"])
    lc = LearnConfig(start=hil.task.start, goal=hil.task.goal, sessions=2, cycles=2,
                     arms=("chip",))
    model = DeviceModel.from_dict(json.loads(Path(model_path).read_text()))
    folder = open_run(out, "learn", {"test": "lost board"}, resume=resume)
    client.wait_for_workers(2)                  # a killed worker is back (its nanny)
    boards = BoardSet(tuple(ports), None, LinkOptions(),
                      FileUse(record=True, updates_layout=True), reassign=reassign)
    done = run_on_boards(LearnJob(hil.model, lc, model), boards,
                         RunOptions(folder=folder, seed=lc.seed, command="snan-hil learn"),
                         task=task, client=client)
    doc = done.result
    doc["units"] = board_units(done.units, done.records)
    return doc


def _history_pulses(chip):
    """The pulses every learn run in the history of the emulated chip ``chip`` recorded."""
    from snan_hil.records.history import History
    with History.open(chip.with_suffix(".history.sqlite"), create=False) as db:
        return sum(r.pulses for r in db.runs("learn"))


def _board_pulses(doc, board):
    return sum(r["set"] + r["reset"] for r in doc["ledger"]["rows"] if r["board"] == board)


def test_reassign_moves_a_lost_boards_session_reprogrammed_with_no_pulse_counted_twice(
        device_model, lent, tmp_path):
    """Board 1 dies inside session 1 after a cycle's pulses: with reassign, session 1 goes
    on on board 0 from its last committed cycle, board 0's chip reprogrammed first; the
    pulses board 1 applied stay counted once, on board 1 (its ledger rows = its history),
    board 0's = its history; units record the move."""
    chips = [tmp_path / "m0.npz", tmp_path / "m1.npz"]
    out = tmp_path / "out"
    doc = _learn(lent, device_model, [emu(c) for c in chips], out, task=dying_learner_1,
                 reassign=True)
    units = doc["units"]
    assert units["0"]["board"] == 0 and "moved_from" not in units["0"]
    assert units["1"]["board"] == 0 and units["1"]["moved_from"] == 1
    at = units["1"]["moved_at_cycle"]
    assert at in (1, 2)
    s1 = doc["arms"]["chip"]["sessions"][1]
    assert len(s1["test_steps"]) == 3 and len(s1["pulses"]) == 2         # every cycle
    rows = [(r["board"], r["cycle"], r["stage"]) for r in doc["ledger"]["rows"]
            if r["session"] == 1]
    assert rows[:2] == [(1, 0, "program"), (1, at, "learn (board lost)")]
    assert rows[2] == (0, at, "reprogram")
    assert [c for b, c, _s in rows[3:]] == list(range(at, 3)) and \
        {b for b, _c, _s in rows[3:]} == {0}
    lost = next(r for r in doc["ledger"]["rows"] if r["stage"] == "learn (board lost)")
    journal = read_journal(out / "checkpoint" / "pulses-board-1.jsonl")
    assert lost["set"] + lost["reset"] == sum(1 for p in journal.pulses if p.state == "done"
                                              and p.unit == f"chip-s1-c{at}") > 0
    assert all(p.board == 1 for p in journal.pulses)
    moved = [p for p in read_journal(out / "checkpoint" / "pulses-board-0.jsonl").pulses
             if p.unit.startswith("chip-s1-")]
    assert moved and all(p.board == 0 for p in moved)       # board 0's own journal
    for b, chip in enumerate(chips):                        # each pulse counted once
        assert _board_pulses(doc, b) == _history_pulses(chip) > 0, b
    assert doc["ledger"]["total"] == sum(_history_pulses(c) for c in chips)
    assert sum(doc["ledger"]["per_cell"].values()) == doc["ledger"]["total"]


def test_without_reassign_a_lost_boards_session_resumes_on_it(device_model, lent, tmp_path):
    """Without reassign: one line, the finished cycles kept; --resume puts session 1 back on
    board 1 (no move), and the ledger still equals each board's history."""
    chips = [tmp_path / "n0.npz", tmp_path / "n1.npz"]
    out = tmp_path / "out"
    with pytest.raises(UserError, match=r"board 1 .* was lost .*--resume.*--reassign") as e:
        _learn(lent, device_model, [emu(c) for c in chips], out, task=dying_learner_1)
    assert "\n" not in str(e.value)
    assert (out / "checkpoint" / "unit-chip-s0-c2.json").is_file()      # board 0's session
    assert not (out / "checkpoint" / "unit-chip-s1-c2.json").exists()
    doc = _learn(lent, device_model, [emu(c) for c in chips], out, resume=True)
    assert [doc["units"][k]["board"] for k in ("0", "1")] == [0, 1]
    assert "moved_from" not in doc["units"]["1"]
    assert {r["board"] for r in doc["ledger"]["rows"] if r["session"] == 1} == {1}
    for b, chip in enumerate(chips):
        assert _board_pulses(doc, b) == _history_pulses(chip) > 0, b
