"""program-weights / read-weights / retention through the CLI on the in-process emulator."""

import json

import numpy as np
import pytest

from snan_hil.calibration.testing import grid_weights, session_of
from snan_hil.tools import cli


@pytest.fixture
def emu_env(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    return tmp_path


def test_program_read_retention_roundtrip(emu_env, capsys, mcu):
    d = emu_env
    w = grid_weights(3, 3, seed=4, k=2)
    np.save(d / "w.npy", w)
    code = cli.main(["program-weights", str(d / "w.npy"), "--weight-set", "1", "--port", "emu",
                     "--mcu", mcu, "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert out["summary"]["cells"] == 24 and out["summary"]["ok"] == 24
    # defaults: layout and report next to the emulator's chip file
    assert out["layout"] == str(d / "chip.layout.json")
    report = json.loads((d / "chip.program-report.json").read_text())
    assert report["complete"] and len(report["cells"]) == 24
    assert report["weights"]["set_index"] == 1

    code = cli.main(["read-weights", "--port", "emu", "--mcu", mcu, "-o", str(d / "read.npy"),
                     "--weights", str(d / "w.npy"), "--weight-set", "1", "--json"])
    res = json.loads(capsys.readouterr().out)
    assert code == 0
    read = np.load(d / "read.npy")
    mask = w[1] > 0
    assert read.shape == (9, 9) and np.all(read[~mask] == 0)
    assert np.max(np.abs(read[mask] - w[1][mask])) < 0.06
    assert res["errors"]["max_abs"] == pytest.approx(np.max(np.abs(read - w[1])), rel=1e-6)
    # against the other weight set the error is large: the comparison is real
    code = cli.main(["read-weights", "--port", "emu", "--mcu", mcu, "--weights",
                     str(d / "w.npy"), "--weight-set", "0", "--json"])
    assert json.loads(capsys.readouterr().out)["errors"]["mean_abs"] > 0.15

    code = cli.main(["retention", "--port", "emu", "--mcu", mcu, "--reads", "40", "--json",
                     "-o", str(d / "ret.json")])
    ret = json.loads(capsys.readouterr().out)
    assert code == 0 and ret["summary"]["cells"] == 24 and ret["summary"]["stable"] == 24
    assert json.loads((d / "ret.json").read_text())["summary"]["reads"] == 40


def test_program_weights_table_output_and_rerun(emu_env, capsys, mcu):
    d = emu_env
    np.save(d / "w.npy", grid_weights(3, 3, seed=9))
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--mcu", mcu,
                     "--layout", str(d / "my.json"), "--report", str(d / "rep.json")]) == 0
    out = capsys.readouterr().out
    assert "program-weights summary" in out and "24" in out
    first = json.loads((d / "rep.json").read_text())["summary"]["host_pulses"]
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--mcu", mcu,
                     "--layout", str(d / "my.json"), "--report", str(d / "rep.json")]) == 0
    second = json.loads((d / "rep.json").read_text())["summary"]["host_pulses"]
    assert first > 0 and second < 0.25 * first


@pytest.mark.parametrize("argv,needle", [
    (["--tolerance", "1.5"], "--tolerance"),
    (["--g-min-us", "500", "--g-max-us", "100"], "G_min < G_max"),
    (["--v-max", "1.6"], "above the board's write limit"),
])
def test_bad_options_exit_2(emu_env, capsys, argv, needle):
    np.save(emu_env / "w.npy", grid_weights(3, 3))
    code = cli.main(["program-weights", str(emu_env / "w.npy"), "--port", "emu", *argv])
    err = capsys.readouterr().err
    assert code == 2 and needle in err and err.count("\n") == 1


def test_read_weights_without_layout_exits_2(emu_env, capsys):
    code = cli.main(["read-weights", "--port", "emu", "--layout", str(emu_env / "none.json")])
    err = capsys.readouterr().err
    assert code == 2 and "does not exist" in err


def test_a_run_that_fails_before_programming_leaves_no_stale_complete_report(emu_env, capsys):
    """Issue 17, point 8: HELLO fails (a board that never answers: exit 3, the board or its
    link failed): the previous run's complete report is replaced by one marked incomplete
    with the error."""
    import socket
    d = emu_env
    np.save(d / "w.npy", grid_weights(3, 3, seed=9))
    common = [str(d / "w.npy"), "--layout", str(d / "l.json"), "--report", str(d / "r.json")]
    assert cli.main(["program-weights", *common, "--port", "emu"]) == 0
    capsys.readouterr()
    good = (d / "r.json").read_text()
    assert json.loads(good)["complete"] is True
    mute = socket.create_server(("127.0.0.1", 0))           # accepts, never answers
    try:
        host, port = mute.getsockname()[:2]
        code = cli.main(["program-weights", *common, "--port", f"socket://{host}:{port}",
                         "--timeout", "0.05"])
    finally:
        mute.close()
    err = capsys.readouterr().err
    assert code == cli.EXIT_BOARD_OR_LINK and "no byte at all" in err and err.count("\n") == 1
    report = json.loads((d / "r.json").read_text())
    assert report["complete"] is False and "no byte at all" in report["error"]
    assert report["format"] == "snan-hil-program-report/1" and report["cells"] == []
    # finding 6: the last complete report is kept, unchanged, as r.prev.json
    assert (d / "r.prev.json").read_text() == good
    # a second failure keeps it too (the incomplete report is not rotated over it)
    mute = socket.create_server(("127.0.0.1", 0))
    try:
        host, port = mute.getsockname()[:2]
        assert cli.main(["program-weights", *common, "--port", f"socket://{host}:{port}",
                         "--timeout", "0.05"]) == cli.EXIT_BOARD_OR_LINK
    finally:
        mute.close()
    assert (d / "r.prev.json").read_text() == good
    assert json.loads((d / "r.json").read_text())["complete"] is False


def test_a_user_mistake_found_at_the_board_leaves_the_last_report_alone(emu_env, capsys):
    # found by a new user: --max-write-v above the board's declared limit (exit 2, one line)
    # replaced the complete report by one "HostSafetyError" report and rotated the good one
    d = emu_env
    np.save(d / "w.npy", grid_weights(3, 3, seed=9))
    common = [str(d / "w.npy"), "--layout", str(d / "l.json"), "--report", str(d / "r.json"),
              "--port", "emu"]
    assert cli.main(["program-weights", *common]) == 0
    good = (d / "r.json").read_text()
    capsys.readouterr()
    assert cli.main(["program-weights", *common, "--max-write-v", "2.0"]) == 2
    err = capsys.readouterr().err
    assert "above the board's declared write limit" in err and err.count("\n") == 1, err
    assert (d / "r.json").read_text() == good and not (d / "r.prev.json").exists()


def test_a_lowered_host_limit_lowers_the_default_amplitude(emu_env, capsys):
    # found by a new user: --max-write-v 1.0 alone was refused ("--v-max 1.4 V is above the
    # host's write limit") although --v-max was never given
    d = emu_env
    np.save(d / "w.npy", grid_weights(3, 3, seed=9))
    assert cli.main(["program-weights", str(d / "w.npy"), "--layout", str(d / "l.json"),
                     "--report", str(d / "r.json"), "--port", "emu", "--max-write-v", "1.2",
                     "--json"]) == 0
    report = json.loads((d / "r.json").read_text())
    assert report["config"]["wv"]["v_max"] == 1.2
    assert cli.main(["cells", "test", "--cells", "3,5", "--port", "emu", "--max-write-v", "1.2",
                     "-o", str(d / "c.json")]) == 0
    capsys.readouterr()
    assert cli.main(["cells", "test", "--cells", "3,5", "--port", "emu", "--v-max", "nan",
                     "-o", str(d / "c2.json")]) == 2
    assert "--v-max nan: give a number of volts" in capsys.readouterr().err


def test_a_foreign_file_where_the_previous_report_goes_is_refused_first(emu_env, capsys):
    d = emu_env
    np.save(d / "w.npy", grid_weights(3, 3, seed=9))
    (d / "r.prev.json").write_text("my notes\n")
    code = cli.main(["program-weights", str(d / "w.npy"), "--layout", str(d / "l.json"),
                     "--report", str(d / "r.json"), "--port", "emu"])
    err = capsys.readouterr().err
    assert code == 2 and "r.prev.json" in err and err.count("\n") == 1, err
    assert (d / "r.prev.json").read_text() == "my notes\n" and not (d / "l.json").exists()


def test_a_failing_first_status_writes_an_incomplete_report(tmp_path):
    from snan_hil.calibration.programmer import program_weights
    from snan_hil.firmware_emu.inprocess import open_inprocess_transport
    from snan_hil.protocol.errors import LinkTimeoutError
    from snan_hil.protocol import messages as m
    from snan_hil.protocol.link import LinkClient

    class NoStatus(LinkClient):
        def request(self, req, **kwargs):
            if isinstance(req, m.Status):
                raise LinkTimeoutError("no reply to STATUS (test)", "corrupting")
            return super().request(req, **kwargs)

    report = tmp_path / "r.json"
    report.write_text(json.dumps({"format": "snan-hil-program-report/1", "complete": True}))
    client = NoStatus(open_inprocess_transport(state_file=str(tmp_path / "chip.npz")))
    try:
        client.hello()
        with pytest.raises(LinkTimeoutError):
            program_weights(session_of(client, tmp_path / "l.json", report),
                            grid_weights(3, 3), {"grid": [3, 3]})
    finally:
        client.close()
    data = json.loads(report.read_text())
    assert data["complete"] is False and "no reply to STATUS" in data["error"]
    assert json.loads((tmp_path / "r.prev.json").read_text())["complete"] is True


@pytest.mark.parametrize("argv,needle", [
    (["--z-limit", "nan"], "--z-limit must be a positive number"),
    (["--z-limit", "-1"], "--z-limit must be a positive number"),
    (["--z-limit", "inf"], "--z-limit must be a positive number"),
    (["--reads", "10000000000"], "reads of 24 cells needs about"),
])
def test_retention_refuses_bad_limits_and_oversized_series_in_one_line(emu_env, capsys, argv,
                                                                       needle):
    """Issue 27 items 11/13: no traceback for a NaN or negative --z-limit or for more reads
    than memory holds; nothing is read or recorded first."""
    np.save(emu_env / "w.npy", grid_weights(3, 3, seed=4))
    assert cli.main(["program-weights", str(emu_env / "w.npy"), "--port", "emu",
                     "--json"]) == 0
    capsys.readouterr()
    reads = [] if "--reads" in argv else ["--reads", "5"]     # an option is given once
    code = cli.main(["retention", "--port", "emu", *reads, *argv])
    err = capsys.readouterr().err
    assert code == 2 and needle in err and err.count("\n") == 1, err


def test_weights_read_back_program_back_even_at_the_window_edges(emu_env, capsys):
    """Issue 27 item 13: weights programmed at exactly 0 and 1 read back slightly outside
    [0, 1] (read noise) and the read-back file was refused by program-weights. The file is
    written inside the window (the JSON counts the clipped reads; errors are of the reads)."""
    w = grid_weights(3, 3, seed=4)
    syn = np.argwhere(w > 0)
    for i, (a, b) in enumerate(syn):
        w[a, b] = float(i % 2)                       # every synapse at an edge: 0 or 1
    np.save(emu_env / "w.npy", w)
    assert cli.main(["program-weights", str(emu_env / "w.npy"), "--port", "emu",
                     "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["read-weights", "--port", "emu", "-o", str(emu_env / "read.npy"),
                     "--weights", str(emu_env / "w.npy"), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    read = np.load(emu_env / "read.npy")
    assert read.min() >= 0.0 and read.max() <= 1.0
    assert res["clipped_to_window"] > 0          # the premise: some reads fall outside
    assert cli.main(["program-weights", str(emu_env / "read.npy"), "--port", "emu",
                     "--json"]) == 0, capsys.readouterr().err
