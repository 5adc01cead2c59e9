"""Checkpoints of long runs: an output folder that a killed run leaves consistent and resumable.

A run (``compare``, ``demo``, ``experiment``) that writes into ``--out DIR`` keeps
``DIR/checkpoint/``:

* ``run.json``: what run this is — the command, its identity (seed, configuration, inputs and
  their fingerprints, options that change results) and the snan-hil version — and whether it
  is complete;
* one JSON file per finished unit of work (a weight set, a figure's task, a stage), written
  atomically (temporary file, fsync, rename) once the unit is finished, so a kill at any moment
  leaves every unit either complete or absent;
* snapshots the run needs to redo an unfinished unit exactly (the emulated chip and its layout
  at the last unit boundary).

One rule for a reused ``--out``, applied by :func:`check_out` before any work (after the
checks every output gets, :meth:`snan_hil.files.outputs.Outputs.folder`) and again by
:func:`open_run` when the run starts: without ``--resume`` a folder holding an earlier run (a
checkpoint, or result files of the command) is refused with one line that names ``--resume``;
with ``--resume`` the recorded run must be the requested one — every difference is named — and
the finished units are taken from the checkpoint. ``--force`` does not lift this rule (it only
lets a command overwrite files that are not of its own kind). Result files of a run are
written only at its end, from all units, so they never mix an earlier run's results with new
ones.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.common.errors import UserError
from snan_hil.files.outputs import OutputKind, Outputs

__all__ = ["CHECKPOINT_DIR", "RUN_FORMAT", "RunFolder", "open_run", "check_out",
           "earlier_results", "differences", "discard_unstarted", "forget_opened",
           "unfinished_runs"]

log = logging.getLogger(__name__)

CHECKPOINT_DIR = "checkpoint"
RUN_FORMAT = "snan-hil-run/1"


def _canonical(value: Any) -> Any:
    """JSON round trip: tuples become lists, keys strings, so recorded and requested compare."""
    return json.loads(json.dumps(value, sort_keys=True, default=str))


def differences(recorded: Any, requested: Any, prefix: str = "") -> list[str]:
    """``key: recorded -> requested`` for every leaf that differs (dotted keys)."""
    if isinstance(recorded, dict) and isinstance(requested, dict):
        out: list[str] = []
        for key in sorted(set(recorded) | set(requested)):
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in recorded:
                out.append(f"{name}: (none) -> {_short(requested[key])}")
            elif key not in requested:
                out.append(f"{name}: {_short(recorded[key])} -> (none)")
            else:
                out += differences(recorded[key], requested[key], name)
        return out
    if isinstance(recorded, list) and isinstance(requested, list) and recorded != requested:
        name = prefix or "run"        # a list's differing entries (a group's ports), not a cut
        if len(recorded) != len(requested):
            return [f"{name}: {len(recorded)} entries -> {len(requested)}"] + [
                f"{name}[{i}]: {_short(a)} -> {_short(b)}"
                for i, (a, b) in enumerate(zip(recorded, requested)) if a != b]
        out = []
        for i, (a, b) in enumerate(zip(recorded, requested)):
            out += differences(a, b, f"{name}[{i}]")
        return out
    if recorded != requested:
        return [f"{prefix or 'run'}: {_short(recorded)} -> {_short(requested)}"]
    return []


def _short(value: Any, limit: int = 40) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= limit else text[:limit - 3] + "..."


class RunFolder:
    """The checkpoint of one run in ``out`` (made by :func:`open_run`)."""

    def __init__(self, out: Path, command: str, identity: dict[str, Any], record: dict[str, Any],
                 resumed: bool, created_out: bool = False):
        self.out = out
        self.command = command
        self.identity = identity
        self.record = record
        self.resumed = resumed
        self.dir = out / CHECKPOINT_DIR
        self.created_out = created_out
        """Whether this run made ``out`` (a new run; :func:`discard_unstarted` removes it)."""

    def discard(self) -> bool:
        """Remove the checkpoint of a new run that committed no unit (and ``out`` when this
        run made it and it is left empty): a user mistake found after the folder was opened
        leaves it as it was. False (nothing removed) for a resumed run or one with units."""
        if (self.resumed or self.is_complete or not self.dir.is_dir()
                or any(self.dir.glob("unit-*.json"))):
            return False
        shutil.rmtree(self.dir, ignore_errors=True)
        if self.created_out:
            try:
                self.out.rmdir()                  # only when empty: nothing else is touched
            except OSError:
                pass
        log.info("removed the checkpoint of the %s run in %s (nothing was done)",
                 self.command, self.out)
        return True

    # ------------------------------------------------------------------ units
    def unit_path(self, unit: str) -> Path:
        return self.dir / f"unit-{unit}.json"

    def done(self, unit: str) -> dict[str, Any] | None:
        """The data committed for ``unit``, None if it is not finished."""
        path = self.unit_path(unit)
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise UserError(f"checkpoint {path} is unreadable ({exc}); delete it to redo that "
                            "part, or start a new run in another --out") from None
        if not isinstance(data, dict) or data.get("unit") != unit:
            raise UserError(f"checkpoint {path} is not the record of {unit}; delete it to redo "
                            "that part")
        return data["data"]

    def check_units(self) -> None:
        """Read every committed unit (:meth:`done`): UserError (one line) naming the first
        that cannot be used (truncated, not JSON, another unit's), before a resumed run does
        or says anything."""
        for path in sorted(self.dir.glob("unit-*.json")):
            self.done(path.name[len("unit-"):-len(".json")])

    def commit(self, unit: str, data: Mapping[str, Any]) -> None:
        """Record ``unit`` as finished with ``data`` (JSON-able; written atomically)."""
        atomic_write_json(self.unit_path(unit), {"unit": unit, "data": data}, indent=1,
                          allow_nan=False)

    def path(self, name: str) -> Path:
        """A file of the checkpoint (snapshots)."""
        return self.dir / name

    def complete(self) -> None:
        """Mark the run complete (its result files are written)."""
        self.record["status"] = "complete"
        self.record["completed"] = _now()
        if self in _OPENED:
            _OPENED.remove(self)
        atomic_write_json(self.dir / "run.json", self.record, indent=1)

    @property
    def is_complete(self) -> bool:
        return self.record.get("status") == "complete"


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _describe(record: dict[str, Any], folder: Path) -> str:
    ident = record.get("identity", {})
    bits = [f"{record.get('command', '?')} run"]
    if "seed" in ident:
        bits.append(f"seed {ident['seed']}")
    bits.append(f"started {record.get('created', '?')}")
    done = len(list(folder.glob("unit-*.json")))
    status = "complete" if record.get("status") == "complete" else f"{done} part(s) done"
    return f"an earlier {', '.join(bits)} ({status})"


def _read_record(run_json: Path) -> dict[str, Any]:
    try:
        record = json.loads(run_json.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UserError(f"{run_json} is unreadable ({exc}); give a new --out folder") from None
    if not isinstance(record, dict) or record.get("format") != RUN_FORMAT:
        raise UserError(f"{run_json} is not a snan-hil run record; give a new --out folder")
    return record


def _check_run(out: Path, command: str, *, resume: bool,
               earlier: Iterable[str] = ()) -> dict[str, Any] | None:
    """The reused-folder rule (module doc) for ``out``; ``earlier``: names in ``out`` holding
    results of an earlier run. Returns the recorded run when resuming, else None."""
    cdir = out / CHECKPOINT_DIR
    run_json = cdir / "run.json"
    if (cdir.exists() or cdir.is_symlink()) and not cdir.is_dir():
        raise UserError(f"--out {out}: {CHECKPOINT_DIR} exists and is not a folder (a run keeps "
                        "its checkpoint there); move it away or give a new --out folder")
    if run_json.is_file():
        record = _read_record(run_json)
        if not resume and record.get("command") not in (None, command):
            raise UserError(f"--out {out} holds {_describe(record, cdir)}, not a {command} "
                            "run; give a new --out folder")
        if not resume:
            what = ("its results are complete; --resume writes them again from its checkpoint"
                    if record.get("status") == "complete" else "continue it with --resume")
            raise UserError(f"--out {out} holds {_describe(record, cdir)}; {what}, or give a "
                            "new --out folder (or delete this one)")
        if record.get("command") != command:
            raise UserError(f"--resume: {out} holds a {record.get('command')} run, not a "
                            f"{command} run; give its own --out")
        return record
    if cdir.is_dir() and any(p for p in cdir.iterdir() if not p.name.startswith(".")):
        raise UserError(f"--out {out}: {cdir} holds files but no run record (run.json), so it "
                        "is not a snan-hil checkpoint; move it away or give a new --out folder")
    found = sorted(set(earlier))
    if found:
        raise UserError(f"--out {out} holds results of an earlier run ({', '.join(found[:3])}"
                        f"{', ...' if len(found) > 3 else ''}) and no checkpoint to "
                        f"{'resume' if resume else 'continue with --resume'}; give a new --out "
                        "folder (or delete those files)")
    if resume:
        raise UserError(f"--resume: {out} holds no checkpoint of a {command} run; run without "
                        "--resume to start one")
    return None


def earlier_results(out: Path, files: Mapping[str, OutputKind | None] | None = None,
                    folders: Mapping[str, OutputKind] | None = None) -> list[str]:
    """The outputs (names relative to ``out``, first path component) that already hold a
    result of the command: a file of its kind, a non-empty folder of its kind, or in a
    sub-folder the command writes (``programming/``) any file of the kinds it writes there —
    also for weight sets this run does not use. Files of another kind are not results of ours:
    :meth:`Outputs.folder` refuses them (``--force`` overwrites)."""
    found: set[str] = set()
    sub_kinds: dict[str, list[OutputKind]] = {}
    for name, kind in (files or {}).items():
        path = out / name
        top = Path(name).parts[0]
        if kind is not None and path.is_file() and kind.owns(path):
            found.add(top)
        if len(Path(name).parts) > 1 and kind is not None:
            sub_kinds.setdefault(str(Path(name).parent), []).append(kind)
    for sub, kinds in sub_kinds.items():
        folder = out / sub
        if folder.is_dir() and any(f.is_file() and any(k.owns(f) for k in kinds)
                                   for f in folder.iterdir()):
            found.add(Path(sub).parts[0])
    for name, kind in (folders or {}).items():
        path = out / name
        if path.is_dir() and any(path.iterdir()) and kind.owns(path):
            found.add(name)
    return sorted(found)


def check_out(outs: Outputs, out: str | os.PathLike[str] | None, command: str, *,
              resume: bool, files: Mapping[str, OutputKind | None] | None = None,
              folders: Mapping[str, OutputKind] | None = None,
              option: str = "--out") -> Path:
    """Check the output folder of a run before any work (opening a board included); writes
    nothing. First :meth:`snan_hil.files.outputs.Outputs.folder` (a folder or creatable, writable —
    ``/proc``, read-only mounts and ``chattr +i`` are found —, not an input, each of ``files``
    / ``folders`` of its own kind or ``--force``), then the reused-folder rule of the module
    doc: an earlier run's checkpoint needs ``--resume`` (the same command), results of an
    earlier run without a checkpoint (:func:`earlier_results`) are refused. Returns the
    folder (``~`` expanded)."""
    d = outs.folder(option, out, files=files, folders=folders)
    _check_run(d, command, resume=resume, earlier=earlier_results(d, files, folders))
    return d


def open_run(out: str | os.PathLike, command: str, identity: Mapping[str, Any], *,
             resume: bool, outputs: Iterable[str] = ()) -> RunFolder:
    """Open ``out`` for a run of ``command`` with ``identity`` (see the module doc).

    ``outputs``: names (files or folders) the command writes into ``out``; without a
    checkpoint, their presence means results of an earlier run. Raises :class:`UserError`
    (one line) when the folder cannot be used. Creates the folder and the checkpoint.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} exists and is not a folder")
    record = _check_run(out, command, resume=resume,
                        earlier=[name for name in outputs if (out / name).exists()])
    ident = _canonical({**identity, "snan_hil_version": __version__})
    cdir = out / CHECKPOINT_DIR
    if record is not None:
        diff = differences(record.get("identity", {}), ident)
        if diff:
            more = f" (and {len(diff) - 3} more)" if len(diff) > 3 else ""
            raise UserError(f"--resume: the run in {out} was started differently: "
                            + "; ".join(diff[:3]) + more
                            + " (recorded -> requested); give the same options, or a new --out")
        _clean_temporary(cdir)
        folder = RunFolder(out, command, ident, record, resumed=True)
        folder.check_units()            # a damaged unit is refused before "resuming"
        log.info("resuming the %s run in %s", command, out)
        _OPENED.append(folder)
        return folder
    record = {"format": RUN_FORMAT, "command": command, "identity": ident, "created": _now(),
              "status": "running"}
    created_out = not out.exists()
    try:
        cdir.mkdir(parents=True, exist_ok=True)
        atomic_write_json(cdir / "run.json", record, indent=1)
    except OSError as exc:
        raise UserError(f"cannot write into --out {out}: {exc.strerror or exc}") from None
    folder = RunFolder(out, command, ident, record, resumed=False, created_out=created_out)
    _OPENED.append(folder)
    return folder


_OPENED: list[RunFolder] = []
"""The runs this command opened and did not complete (:func:`discard_unstarted`,
:func:`unfinished_runs`)."""


def unfinished_runs() -> list[RunFolder]:
    """The runs this command opened that are not complete (after a Ctrl-C: resumable)."""
    return [f for f in _OPENED if not f.is_complete]


def forget_opened() -> None:
    """Forget the runs opened so far (a new command starts: :func:`discard_unstarted` is
    about its own runs only)."""
    _OPENED.clear()


def discard_unstarted() -> list[Path]:
    """:meth:`RunFolder.discard` every new run this process opened that committed no unit:
    the CLI calls it when a command ends with a user mistake (one line, exit 2) or a failure
    of the board or its link (exit 3), so the corrected command is not refused for the
    checkpoint the failed one left. The runs kept (with units, or resumed) stay
    :func:`unfinished_runs` (the CLI names the command that continues them). The folders
    whose checkpoint was removed."""
    gone = [f for f in _OPENED if f.discard()]
    _OPENED[:] = [f for f in _OPENED if f not in gone]
    return [f.out for f in gone]


def _clean_temporary(folder: Path) -> None:
    """Remove temporary files a killed writer left (``.NAME.XXXX.tmp``)."""
    for tmp in folder.glob(".*.tmp*"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)
        elif tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
