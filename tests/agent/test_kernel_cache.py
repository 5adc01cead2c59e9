"""The numba cache follows the kernel's source.

Numba keys a cached kernel (``cache=True``) on the source file that defines it. A cached
kernel that calls a function (or reads a constant) of *another* file would keep that
function's old code after the other file changes, so `snan-hil sim` and the experiments
could disagree after a `git pull`. The project therefore keeps every numba function in
one self-contained module per kernel — ``host/snan_kernel.py`` (the trial kernel) and
``firmware_emu/spike_fastpath.py`` (the emulated board's spike fast path) — each using
nothing from other project files; these tests check that, and that editing the trial kernel
really recompiles what depends on the edit.
"""

import ast
import builtins
import dis
import os
import pathlib
import shutil
import subprocess
import sys
import textwrap
import types

import numpy as np

import snan_hil
from snan_hil.host import snan_kernel as K

ROOT = pathlib.Path(snan_hil.__file__).resolve().parent
KERNEL = ROOT / "host" / "snan_kernel.py"
#: the modules that may define numba functions (each self-contained)
NUMBA_MODULES = ["common/numba_cache.py",   # numba's compile event (announce_compile): no
                                           # compiled code, plain Python around numba
                 "firmware_emu/lif_fixed.py", "firmware_emu/spike_fastpath.py",
                 "host/snan_kernel.py"]
ALLOWED_IMPORTS = {"__future__", "math", "typing", "numpy", "numba", "numba.core",
                   "numba.experimental",
                   # plain Python around the cache loader, no compiled code (common/numba_cache.py)
                   "snan_hil.common.numba_cache"}


def _project_sources():
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        if rel.parts[0] in ("tests", ".venv", "build") or "site-packages" in rel.parts:
            continue
        yield path


def _imports(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name
        elif isinstance(node, ast.ImportFrom):
            yield node.module or ""


def test_numba_is_used_only_in_the_kernel_modules():
    users = sorted(str(p.relative_to(ROOT)) for p in _project_sources()
                   if any(m == "numba" or m.startswith("numba.") for m in _imports(p)))
    assert users == NUMBA_MODULES


def test_the_kernel_module_imports_nothing_of_the_project():
    assert set(_imports(KERNEL)) <= ALLOWED_IMPORTS


def test_emulator_fast_path_kernels_read_only_their_own_module():
    """The emulator's njit functions may sit beside imports of the project (its Python side
    uses them) but read only names their own file defines, or numpy/math."""
    from numba.core.registry import CPUDispatcher

    from snan_hil.firmware_emu import spike_fastpath as S
    src = ast.parse(pathlib.Path(S.__file__).read_text(encoding="utf-8"))
    own = {t.id for n in src.body if isinstance(n, ast.Assign) for t in ast.walk(n)
           if isinstance(t, ast.Name)}
    own |= {n.name for n in src.body if isinstance(n, ast.FunctionDef)}
    kernels = [o for o in vars(S).values() if isinstance(o, CPUDispatcher)]
    assert kernels
    for k in kernels:
        for name in _global_names(k.py_func.__code__):
            assert (name in own or name in ("np", "math") or hasattr(builtins, name)), \
                f"{k.py_func.__name__} reads {name}, defined in another file"


def _global_names(code):
    for ins in dis.get_instructions(code):
        if ins.opname in ("LOAD_GLOBAL", "LOAD_NAME"):
            yield ins.argval
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _global_names(const)


def _allowed(obj):
    if obj in (np, __import__("math")):
        return True
    if isinstance(obj, (bool, int, float, str, np.integer, np.floating)):
        return True
    module = getattr(obj, "__module__", None)
    if module == K.__name__:
        return True
    py_func = getattr(obj, "py_func", None)   # a numba dispatcher
    return py_func is not None and py_func.__module__ == K.__name__


def test_every_kernel_uses_only_names_of_its_own_module():
    kernels = {n: o for n, o in vars(K).items() if hasattr(o, "py_func")}
    assert len(kernels) > 30
    bad = []
    for name, disp in kernels.items():
        for g in set(_global_names(disp.py_func.__code__)):
            if g in vars(K):
                if not _allowed(vars(K)[g]):
                    bad.append(f"{name} uses {g}")
            elif not hasattr(builtins, g):
                bad.append(f"{name} uses unknown {g}")
    assert not bad, bad


_PROBE = textwrap.dedent("""
    import numpy as np
    import kcopy as K
    counts = np.array([3, 5, 5, 1], dtype=np.int64)
    tied = np.zeros(4, dtype=np.int64)
    # choose_lane (cached) calls pick_index: an edit of pick_index must reach it
    print(K.choose_lane(counts, 4, np.uint64(0xFFFFFFFFFFFFFFFF), False, tied))
""")


def _probe(tmp, env):
    out = subprocess.run([sys.executable, "-c", _PROBE], cwd=tmp, env=env, text=True,
                         capture_output=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()[-1], out.stdout + out.stderr


def test_an_edited_kernel_source_is_recompiled(tmp_path):
    shutil.copy(KERNEL, tmp_path / "kcopy.py")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), NUMBA_DEBUG_CACHE="1",
               PYTHONPATH=str(tmp_path))
    first, _ = _probe(tmp_path, env)
    again, log = _probe(tmp_path, env)
    assert again == first and "data loaded" in log      # the cache is really used
    src = (tmp_path / "kcopy.py").read_text(encoding="utf-8")
    old = "    return np.int64(((z >> _S11) * np.uint64(n)) >> _S53)"
    assert old in src
    (tmp_path / "kcopy.py").write_text(src.replace(old, "    return np.int64(0)"),
                                       encoding="utf-8")
    edited, _ = _probe(tmp_path, env)
    assert first == "2" and edited == "1"   # lanes 1 and 2 tie; the edit picks the first


DAMAGE = """
import logging, sys
logging.basicConfig(level=logging.WARNING, format="%(message)s")
sys.path.insert(0, sys.argv[1])
import tiny_kernel
print(tiny_kernel.twice(21))
"""


def test_a_damaged_cache_entry_is_compiled_again_not_a_failure_of_every_run(tmp_path):
    """Issue 27 item 11: a truncated numba cache file made every run fail until deleted by
    hand. A kernel module that calls tolerate_damaged_cache(globals()) treats it as a miss:
    it warns once, removes the entry, compiles again and caches afresh."""
    (tmp_path / "tiny_kernel.py").write_text(textwrap.dedent("""
        from numba import njit

        @njit(cache=True)
        def twice(x):
            return 2 * x

        from snan_hil.common.numba_cache import tolerate_damaged_cache
        tolerate_damaged_cache(globals())
    """))

    def run():
        return subprocess.run([sys.executable, "-c", DAMAGE, str(tmp_path)], capture_output=True,
                              text=True, timeout=300)
    first = run()
    assert first.returncode == 0 and first.stdout.split() == ["42"], first.stderr
    data = sorted((tmp_path / "__pycache__").glob("tiny_kernel.twice-*.nbc"))
    assert data
    for f in data:                                   # cut every data file short
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    damaged = run()
    assert damaged.returncode == 0 and damaged.stdout.split() == ["42"], damaged.stderr
    assert "could not be read" in damaged.stderr and "compiling it again" in damaged.stderr
    again = run()                                    # cached afresh: no warning any more
    assert again.returncode == 0 and "could not be read" not in again.stderr, again.stderr
