"""The first run after an install compiles the trial kernel (about a minute): `sim` and `demo`
(and `learn`) say so in one line on stderr, terminal or not, and the speed they report (`wall_s`,
`decisions_per_s`) is the kernel's alone, without the compilation."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import time

from snan_hil.host import simulate as S
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import load_config
from snan_hil.tools import cli
from snan_hil.tools.commands import sim as sim_cmd


def test_kernel_cached_follows_numbas_compiled_and_on_disk_state(tmp_path):
    """A cache=True function in a fresh module: not cached before its first call, cached in
    the process after it, and cached (numba's index of the current source) in a new process."""
    (tmp_path / "tiny_kernel.py").write_text(textwrap.dedent("""
        from numba import njit

        @njit(cache=True)
        def plus_one(x):
            return x + 1
    """))
    sys.path.insert(0, str(tmp_path))
    try:
        import tiny_kernel
        assert not S.kernel_cached(tiny_kernel.plus_one)
        assert tiny_kernel.plus_one(1) == 2
        assert S.kernel_cached(tiny_kernel.plus_one)
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("tiny_kernel", None)
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import tiny_kernel; "
            "from snan_hil.host.simulate import kernel_cached; "
            "print(kernel_cached(tiny_kernel.plus_one))")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "True"
    (tmp_path / "tiny_kernel.py").write_text(          # an edited kernel: cold again
        (tmp_path / "tiny_kernel.py").read_text().replace("x + 1", "x + 2"))
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "False"


def test_wall_time_is_the_kernels_without_the_compilation(monkeypatch):
    """The first call of the batch kernel stands for the compilation (0.5 s here): simulate's
    wall_s must not contain it."""
    real = K.run_batch_kernel
    calls = []

    def slow_first(*args):
        if not calls:
            time.sleep(0.5)
        calls.append(args[3].shape[0])
        return real(*args)

    monkeypatch.setattr(K, "run_batch_kernel", slow_first)
    res = S.simulate(load_config(preset="snan-3x3"), 3, seed=1)
    assert calls[0] == 0 and sum(calls) == 3          # an empty warm-up batch, then the trials
    assert res.wall_s < 0.5
    assert res.summary()["decisions_per_s"] == res.decisions / res.wall_s


def test_sim_says_when_the_kernel_compiles(monkeypatch, capsys):
    monkeypatch.setattr(sim_cmd, "kernel_cached", lambda: False)
    assert cli.main(["sim", "--trials", "2", "--json"]) == 0
    cap = capsys.readouterr()
    assert sim_cmd.COMPILE_NOTE in cap.err and json.loads(cap.out)["trials"] == 2
    assert cap.err.count("compiling the trial kernel") == 1
    monkeypatch.setattr(sim_cmd, "kernel_cached", lambda: True)
    assert cli.main(["sim", "--trials", "2", "--json"]) == 0
    assert "compiling" not in capsys.readouterr().err


def test_announce_compile_calls_once_and_only_when_numba_compiles():
    from numba import njit

    from snan_hil.common.numba_cache import announce_compile

    @njit
    def times_three(x):
        return 3 * x

    said = []
    with announce_compile(lambda: said.append(1)):
        assert times_three(2) == 6          # compiles: told once
        assert times_three(2.5) == 7.5      # a second signature compiles too: not told again
    assert said == [1]
    with announce_compile(lambda: said.append(2)):
        assert times_three(4) == 12         # compiled already: nothing to tell
    assert said == [1]


def test_learn_says_compiling_only_when_something_compiles(tmp_path, monkeypatch, capsys):
    # issue 38 item 8: the note was predicted from numba's cache index and printed on starts
    # where nothing compiled; here the prediction would say "cold" on a warm cache
    from snan_hil.tools.commands import learn as learn_cmd
    monkeypatch.setattr(S, "kernel_cached", lambda kernel=None: False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    argv = ["learn", "--arms", "software", "--sessions", "1", "--cycles", "1", "--json"]
    assert cli.main([*argv, "--out", str(tmp_path / "a")]) == 0     # compiles, if cold
    capsys.readouterr()
    assert cli.main([*argv, "--out", str(tmp_path / "b")]) == 0     # warm now
    cap = capsys.readouterr()
    assert learn_cmd.COMPILE_NOTE not in cap.err and json.loads(cap.out)["arms"]["software"]


def test_learn_says_when_its_kernels_compile_first(emu, monkeypatch, capsys):
    # the note follows numba: a run in which a kernel really compiles says so (here a fresh
    # function compiled inside the run stands for a cold kernel cache), a run that only loads
    # compiled kernels does not (issue 38 item 8: it was predicted, and said on every start)
    from numba import njit

    from snan_hil.tools.commands import learn as learn_cmd
    real = learn_cmd.run_learning
    argv = ["learn", "--arms", "software", "--sessions", "1", "--cycles", "1", "--no-figure",
            "--set", "grid.max_steps=10", "--json"]
    for cold in (True, False):
        def learning(*a, cold=cold, **k):
            if cold:
                njit(lambda x: x + 1)(1)                  # a kernel compiled in this run
            return real(*a, **k)
        monkeypatch.setattr(learn_cmd, "run_learning", learning)
        assert cli.main([*argv, "--out", str(emu / f"l{cold}")]) == 0
        err = capsys.readouterr().err
        assert err.count("compiling the network kernels") == int(cold), err
