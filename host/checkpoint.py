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

:func:`open_run` is the one rule for a reused ``--out``: without ``--resume`` a folder holding an
earlier run (a checkpoint, or result files of the command) is refused with one line that names
``--resume``; with ``--resume`` the recorded run must be the requested one — every difference is
named — and the finished units are taken from the checkpoint. Result files of a run are written
only at its end, from all units, so they never mix an earlier run's results with new ones.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import logging
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from snan_hil import __version__
from snan_hil.atomicio import atomic_write_json
from snan_hil.errors import UserError

__all__ = ["CHECKPOINT_DIR", "RUN_FORMAT", "RunFolder", "open_run", "check_out",
           "file_fingerprint", "differences"]

log = logging.getLogger(__name__)

CHECKPOINT_DIR = "checkpoint"
RUN_FORMAT = "snan-hil-run/1"


def file_fingerprint(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (16 hex digits): an input of a run, recorded and compared on
    resume."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


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
    if recorded != requested:
        return [f"{prefix or 'run'}: {_short(recorded)} -> {_short(requested)}"]
    return []


def _short(value: Any, limit: int = 40) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= limit else text[:limit - 3] + "..."


class RunFolder:
    """The checkpoint of one run in ``out`` (made by :func:`open_run`)."""

    def __init__(self, out: Path, command: str, identity: dict[str, Any], record: dict[str, Any],
                 resumed: bool):
        self.out = out
        self.command = command
        self.identity = identity
        self.record = record
        self.resumed = resumed
        self.dir = out / CHECKPOINT_DIR

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

    def done_units(self, units: Iterable[str]) -> list[str]:
        return [u for u in units if self.unit_path(u).is_file()]

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


def check_out(out: str | os.PathLike, command: str, *, resume: bool,
              outputs: Iterable[str] = ()) -> dict[str, Any] | None:
    """The checks of :func:`open_run` that need no identity, to run before any work (opening
    a board included); writes nothing. Returns the recorded run when resuming, else None."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} exists and is not a folder")
    cdir = out / CHECKPOINT_DIR
    run_json = cdir / "run.json"
    if run_json.is_file():
        record = _read_record(run_json)
        if not resume:
            what = ("its results are complete; --resume writes them again from its checkpoint"
                    if record.get("status") == "complete" else "continue it with --resume")
            raise UserError(f"--out {out} holds {_describe(record, cdir)}; {what}, or give a "
                            "new --out folder (or delete this one)")
        if record.get("command") != command:
            raise UserError(f"--resume: {out} holds a {record.get('command')} run, not a "
                            f"{command} run; give its own --out")
        return record
    found = sorted(name for name in outputs if (out / name).exists())
    if found:
        raise UserError(f"--out {out} holds results of an earlier run ({', '.join(found[:3])}"
                        f"{', ...' if len(found) > 3 else ''}) and no checkpoint to "
                        f"{'resume' if resume else 'continue with --resume'}; give a new --out "
                        "folder (or delete those files)")
    if resume:
        raise UserError(f"--resume: {out} holds no checkpoint of a {command} run; run without "
                        "--resume to start one")
    return None


def open_run(out: str | os.PathLike, command: str, identity: Mapping[str, Any], *,
             resume: bool, outputs: Iterable[str] = ()) -> RunFolder:
    """Open ``out`` for a run of ``command`` with ``identity`` (see the module doc).

    ``outputs``: names (files or folders) the command writes into ``out``; without a
    checkpoint, their presence means results of an earlier run. Raises :class:`UserError`
    (one line) when the folder cannot be used. Creates the folder and the checkpoint.
    """
    out = Path(out)
    record = check_out(out, command, resume=resume, outputs=outputs)
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
        log.info("resuming the %s run in %s", command, out)
        return RunFolder(out, command, ident, record, resumed=True)
    record = {"format": RUN_FORMAT, "command": command, "identity": ident, "created": _now(),
              "status": "running"}
    try:
        cdir.mkdir(parents=True, exist_ok=True)
        atomic_write_json(cdir / "run.json", record, indent=1)
    except OSError as exc:
        raise UserError(f"cannot write into --out {out}: {exc.strerror or exc}") from None
    return RunFolder(out, command, ident, record, resumed=False)


def _clean_temporary(folder: Path) -> None:
    """Remove temporary files a killed writer left (``.NAME.XXXX.tmp``)."""
    for tmp in folder.glob(".*.tmp*"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)
        elif tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
