"""Output paths, checked before any long work; a command never overwrites another kind of file.

Every command that writes files checks each of its outputs here before it starts anything
long (opening a board, training, programming, simulating)::

    outs = Outputs(inputs={"weights": args.weights, "--layout": layout_path}, force=args.force)
    layout_path = outs.file("--layout", layout_path, LAYOUT, updates=True)
    report_path = outs.file("--report", args.report, PROGRAM_REPORT)
    out = outs.folder("--out", args.out, files={"compare.json": COMPARE_JSON})

Each failure is one :class:`OutputError` line (exit code 2) naming the option, the path, what
is wrong and what to do:

* an output file is not an existing folder, device or pipe; an output folder is not a file;
* it is not one of the command's inputs (the same file by device and inode, so a link or
  another spelling of the path is found too), unless ``updates`` says the command reads and
  rewrites it (``program-weights`` and its layout); two outputs are not the same file;
* its folder exists (or, with ``create_folder``, its nearest existing ancestor is a folder
  it can be created in) and a file can be created there: probed by creating an unnamed
  temporary file, so read-only mounts, ``chattr +i`` folders and ``/proc`` are found also
  when permission bits say nothing (root);
* an existing file is of the output's own kind (:class:`OutputKind`: a JSON ``format``
  field, an ``.npz`` ``format`` member, a CSV header, a PNG text tag; see the factories) —
  anything else is overwritten only with ``force`` (the CLI's ``--force``).

Writing itself goes through :mod:`snan_hil.files.atomicio` (temporary file + rename, umask
permissions). A base module like :mod:`snan_hil.common.errors`: every layer may import it.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import tempfile
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snan_hil.files.atomicio import signals_deferred
from snan_hil.common.errors import UserError

__all__ = ["OutputError", "OutputKind", "Outputs", "json_kind", "npz_kind", "csv_kind",
           "png_kind", "png_metadata", "PNG_KEY", "check_output_file", "check_output_folder"]

PNG_KEY = "snan-hil"
"""PNG text key whose value marks a figure written by snan-hil (:func:`png_metadata`)."""

_JSON_LIMIT = 64 << 20       # larger "JSON" files are not ours


class OutputError(UserError):
    """An output path that cannot or must not be written (one line, exit code 2)."""


@dataclass(frozen=True)
class OutputKind:
    """What a command writes: ``name`` for messages ("a snan-hil layout"), ``owns(path)``
    True when an existing file (or folder) is one of its own and may be replaced."""

    name: str
    owns: Callable[[Path], bool]
    suffix: str | None = None
    """The file name must end in this (``.png`` for figures: the data is PNG whatever the
    name says), None: any name."""


def _family(fmt: str) -> str:
    """``"snan-hil-layout/1"`` -> ``"snan-hil-layout/"``: any version of the format."""
    return fmt.split("/", 1)[0] + "/"


def json_kind(fmt: str, name: str) -> OutputKind:
    """A JSON object whose ``"format"`` is ``fmt`` or another version of it."""
    family = _family(fmt)

    def owns(path: Path) -> bool:
        try:
            if path.stat().st_size > _JSON_LIMIT:
                return False
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        return isinstance(data, dict) and str(data.get("format", "")).startswith(family)
    return OutputKind(name, owns)


def npz_kind(fmt: str, name: str) -> OutputKind:
    """An ``.npz`` whose ``format`` member is the text ``fmt`` or another version of it."""
    family = _family(fmt)

    def owns(path: Path) -> bool:
        try:
            with zipfile.ZipFile(path) as z, z.open("format.npy") as fh:
                value = np.lib.format.read_array(fh, allow_pickle=False)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            return False
        return value.dtype.kind in "US" and value.size == 1 and \
            str(value.reshape(())).startswith(family)
    return OutputKind(name, owns)


def csv_kind(header: str, name: str, earlier: tuple[str, ...] = ()) -> OutputKind:
    """A CSV file whose first line is ``header`` (column names joined by commas) or one of
    the ``earlier`` headers (the same file as written by an earlier version, before columns
    were added)."""
    headers = {header, *earlier}
    longest = max(len(h) for h in headers)

    def owns(path: Path) -> bool:
        try:
            with open(path, encoding="utf-8", newline="") as fh:
                first = fh.readline(longest + 3)
        except (OSError, ValueError):
            return False
        return first.rstrip("\r\n") in headers
    return OutputKind(name, owns)


def png_metadata(fmt: str) -> dict[str, str]:
    """``savefig(..., metadata=png_metadata(FMT))`` marks a PNG as snan-hil's (text chunk
    :data:`PNG_KEY`)."""
    return {PNG_KEY: fmt}


def png_kind(fmt: str, name: str) -> OutputKind:
    """A PNG carrying ``png_metadata(fmt)`` (or another version of ``fmt``); read with
    Pillow (matplotlib's dependency), without it no PNG is recognised."""
    family = _family(fmt)

    def owns(path: Path) -> bool:
        try:
            from PIL import Image
            with Image.open(path) as im:
                text = getattr(im, "text", {}) or {}
        except Exception:        # noqa: BLE001 - any unreadable file is simply not ours
            return False
        return str(text.get(PNG_KEY, "")).startswith(family)
    return OutputKind(name, owns, ".png")


def _reason(exc: OSError) -> str:
    if exc.errno == errno.ENOENT:           # an existing folder: /proc, /sys and the like
        return "no files can be created there"
    return exc.strerror or str(exc)


def _describe(path: Path) -> str | None:
    """What an existing non-regular, non-folder path is, or None."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    if stat.S_ISDIR(mode) or stat.S_ISREG(mode):
        return None
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


class Outputs:
    """The outputs of one command run, checked one by one against its inputs and each other.

    ``inputs`` maps an option name (or a word such as "weights") to a path the command reads;
    missing or empty entries are ignored. ``force`` allows overwriting existing files that are
    not of the output's kind (never inputs, folders or devices).
    """

    def __init__(self, inputs: Mapping[str, str | os.PathLike[str] | None] | None = None, *,
                 force: bool = False) -> None:
        self.inputs = {k: Path(v).expanduser() for k, v in (inputs or {}).items()
                       if v is not None and str(v)}
        self.force = force
        self.outputs: dict[str, Path] = {}
        self._writable: dict[Path, str | None] = {}

    # ------------------------------------------------------------------ folders
    def _probe(self, folder: Path) -> str | None:
        """None if a file can be created in ``folder``, else the reason."""
        key = folder.resolve()
        if key not in self._writable:
            try:
                with signals_deferred(), tempfile.TemporaryFile(dir=key):
                    pass                                     # O_TMPFILE: it never has a name
                self._writable[key] = None
            except OSError as exc:
                self._writable[key] = _reason(exc)
        return self._writable[key]

    def _check_folder(self, label: str, folder: Path, *, create: bool) -> None:
        """``folder`` exists and is writable, or (``create``) can be created."""
        if folder.is_dir():
            why = self._probe(folder)
            if why is not None:
                raise OutputError(f"{label}: cannot write in folder {folder} ({why}); give a "
                                  "writable folder")
            return
        if folder.exists() or folder.is_symlink():
            raise OutputError(f"{label}: {folder} is not a folder; give a path in a folder")
        ancestor = folder.parent
        while not ancestor.exists() and not ancestor.is_symlink() and ancestor != ancestor.parent:
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise OutputError(f"{label}: cannot create folder {folder}: {ancestor} is not a "
                              "folder; give a path in a folder")
        if not create:
            raise OutputError(f"{label}: folder {folder} does not exist; create it first or "
                              "give another path")
        why = self._probe(ancestor)
        if why is not None:
            raise OutputError(f"{label}: cannot create folder {folder} in {ancestor} ({why}); "
                              "give a writable folder")

    # ------------------------------------------------------------------ files
    def file(self, option: str, path: str | os.PathLike[str] | None, kind: OutputKind | None,
             *, updates: bool = False, create_folder: bool = False,
             label: str | None = None) -> Path:
        """Check the output file ``path`` of ``option`` (see the module doc); returns it as a
        Path (``~`` expanded).

        ``kind`` None: the command cannot recognise its own files (a bare ``.npy``), so any
        existing file needs ``force``. ``updates``: the command reads this file (the input
        of the same ``option``) and rewrites it. ``create_folder``: a missing folder may be
        created (default paths in the user's data folder)."""
        text = "" if path is None else str(path)
        key = label
        label = label or f"{option} {text}"
        if not text.strip():
            raise OutputError(f"{option}: empty file name; give a file name")
        p = Path(text).expanduser()
        real = p.resolve() if p.is_symlink() else p       # atomicio writes through a link
        if real.is_dir():
            raise OutputError(f"{label}: is a folder; give a file name")
        what = _describe(real)
        if what is not None:
            raise OutputError(f"{label}: is {what}, not a file snan-hil may replace; give a "
                              "file name")
        if kind is not None and kind.suffix and p.suffix.lower() != kind.suffix:
            raise OutputError(f"{label}: {kind.name} is written as {kind.suffix[1:].upper()}; "
                              f"give a file name ending in {kind.suffix}")
        exists = real.is_file()
        if exists:
            for name, inp in self.inputs.items():
                if (name == option and updates) or not inp.exists():
                    continue
                if _same_file(real, inp):
                    raise OutputError(f"{label}: is also an input of this command ({name} "
                                      f"{inp}), which the output would destroy; give another "
                                      "file name")
        for name, out in self.outputs.items():
            if real.resolve() == out.resolve() or (exists and out.exists()
                                                    and _same_file(real, out)):
                raise OutputError(f"{label}: is also the output {name}; give two different "
                                  "files")
        self._check_folder(label, real.parent, create=create_folder)
        if exists and not self.force and not (kind is not None and kind.owns(real)):
            mine = (f"exists and is not {kind.name}" if kind is not None
                    else "exists, and snan-hil cannot tell whether it wrote it")
            raise OutputError(f"{label}: {mine}; give another file name, or --force to "
                              "overwrite it")
        self.outputs[key or option] = real
        return p

    def folder(self, option: str, path: str | os.PathLike[str] | None, *,
               files: Mapping[str, OutputKind | None] | None = None,
               folders: Mapping[str, OutputKind] | None = None) -> Path:
        """Check the output folder ``path`` of ``option``: a folder, or creatable; writable;
        and each file it will hold (``files``: name relative to the folder -> kind, sub-folders
        created as needed) and each sub-folder it will replace as a whole (``folders``: name
        -> kind, its ``owns`` judging the existing folder) as :meth:`file` would. Returns
        the folder (``~`` expanded); it is not created here."""
        text = "" if path is None else str(path)
        if not text.strip():
            raise OutputError(f"{option}: empty folder name; give a folder")
        d = Path(text).expanduser()
        label = f"{option} {text}"
        if (d.exists() or d.is_symlink()) and not d.is_dir():
            raise OutputError(f"{label}: exists and is not a folder; give a folder name")
        self._check_folder(label, d, create=True)
        for name, kind in (files or {}).items():
            self.file(option, d / name, kind, create_folder=True,
                      label=f"{label}: {name}")
        for name, kind in (folders or {}).items():
            sub = d / name
            sub_label = f"{label}: {name}"
            if (sub.exists() or sub.is_symlink()) and not sub.is_dir():
                raise OutputError(f"{sub_label}: exists and is not a folder; move it away")
            if sub.is_dir() and not self.force and not kind.owns(sub):
                raise OutputError(f"{sub_label}: folder exists and is not {kind.name} (it is "
                                  "replaced as a whole); move it away, give another "
                                  f"{option}, or --force to replace it")
            for inp_name, inp in self.inputs.items():
                if sub.is_dir() and inp.exists() and sub.resolve() in inp.resolve().parents:
                    raise OutputError(f"{sub_label}: holds the input {inp_name} ({inp}), and "
                                      "the folder is replaced as a whole; give another "
                                      f"{option}")
            self.outputs[sub_label] = sub
        self.outputs[option] = d
        return d


def check_output_file(option: str, path: str | os.PathLike[str] | None,
                      kind: OutputKind | None, *,
                      inputs: Mapping[str, str | os.PathLike[str] | None] | None = None,
                      force: bool = False, create_folder: bool = False) -> Path:
    """One output file of a command: :meth:`Outputs.file` on its own."""
    return Outputs(inputs, force=force).file(option, path, kind, create_folder=create_folder)


def check_output_folder(option: str, path: str | os.PathLike[str] | None, *,
                        inputs: Mapping[str, str | os.PathLike[str] | None] | None = None,
                        force: bool = False,
                        files: Mapping[str, OutputKind | None] | None = None) -> Path:
    """One output folder of a command: :meth:`Outputs.folder` on its own."""
    return Outputs(inputs, force=force).folder(option, path, files=files)
