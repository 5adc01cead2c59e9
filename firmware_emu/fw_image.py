"""The built firmware ELF: where it is, and its loadable segments.

``default_elf_path()`` is ``build/firmware/snan-fw.elf`` in the source tree (``make firmware``
builds it), or ``$SNAN_HIL_FIRMWARE_ELF``. A missing file is one :class:`UserError` line that
says how to build it. :meth:`FirmwareImage.load` validates the file before anything runs it
(a 32-bit little-endian RISC-V executable, not truncated, every loadable segment inside the
MIK32's SPIFI flash or RAM, the entry point in flash) and, in the source tree, that it was built
from the Python definitions of this tree: the ELF carries the hash of its generated constants
header (symbol ``snan_constants_hash``, ``firmware/gen_constants.py``); another hash is a stale
ELF. Each problem is one :class:`UserError` line naming the ELF.
"""

from __future__ import annotations

import importlib.util
import os
import struct
from dataclasses import dataclass
from pathlib import Path

from snan_hil.common.errors import UserError

ELF_ENV = "SNAN_HIL_FIRMWARE_ELF"
_ROOT = Path(__file__).resolve().parent.parent
_GEN_CONSTANTS = _ROOT / "firmware" / "gen_constants.py"
HASH_SYMBOL = "snan_constants_hash"
FLASH = (0x8000_0000, 8 * 1024 * 1024)     # SPIFI flash, executed in place (firmware/link.ld)
RAM = (0x0200_0000, 16 * 1024)
_expected_hash: str | None = None


def default_elf_path() -> Path:
    env = os.environ.get(ELF_ENV)
    return Path(env).expanduser() if env else _ROOT / "build" / "firmware" / "snan-fw.elf"


@dataclass(frozen=True)
class Segment:
    addr: int           # physical (load) address
    vaddr: int
    data: bytes
    memsz: int
    flags: int          # PF_X = 1, PF_W = 2, PF_R = 4


_PARSED: dict[tuple[Path, bytes], "FirmwareImage"] = {}
"""Images already read, by path and contents (all checks passed; shared, not to be changed)."""


@dataclass(frozen=True)
class FirmwareImage:
    path: Path
    entry: int
    segments: tuple[Segment, ...]
    symbols: dict[str, tuple[int, int]]     # name -> (address, size)
    text: tuple[int, bytes]                  # (address, bytes) of .text

    @classmethod
    def load(cls, path: str | os.PathLike | None = None, *,
             check_constants: bool = True) -> "FirmwareImage":
        """Read and validate the ELF (UserError naming it and what is wrong); with
        ``check_constants`` also refuse an ELF built from other Python definitions."""
        p = Path(path) if path is not None else default_elf_path()
        if p.is_dir():
            raise UserError(f"firmware ELF {p} is a directory; give the ELF file (make firmware "
                            f"builds build/firmware/snan-fw.elf), e.g. in {ELF_ENV}")
        if not p.is_file():
            raise UserError(f"firmware ELF {p} not found; build it with 'make firmware' (it "
                            f"needs the [firmware] extra: pip install -e '.[firmware]'), or set "
                            f"{ELF_ENV}")
        try:
            data = p.read_bytes()
        except OSError as exc:
            raise UserError(f"cannot read firmware ELF {p}: {exc.strerror or exc}") from None
        key = (p, data)
        image = _PARSED.get(key)
        if image is not None:                # the same file again (a power cycle)
            return image
        try:
            image = cls._parse(p, data)
        except struct.error:
            raise UserError(f"firmware ELF {p} is truncated ({len(data)} bytes); rebuild it "
                            "with 'make firmware'") from None
        if check_constants:
            image._check_constants(data)
            if len(_PARSED) >= 16:
                _PARSED.clear()
            _PARSED[key] = image             # only what passed every check
        return image

    @classmethod
    def _parse(cls, p: Path, data: bytes) -> "FirmwareImage":
        entry, (phoff, phentsize, phnum), (shoff, shentsize, shnum, shstrndx) = _header(p, data)
        segs = _segments(p, data, phoff, phentsize, phnum)
        if not any(seg.data for seg in segs):
            raise _bad(p, "has no code to load (no loadable segment with contents)")
        if not any(seg.flags & 1 and seg.addr <= entry < seg.addr + len(seg.data)
                   for seg in segs):
            raise _bad(p, f"has its entry point 0x{entry:08x} outside its code in flash; link "
                       "it with firmware/link.ld (make firmware)")
        text, symbols = _sections(data, shoff, shentsize, shnum, shstrndx)
        return cls(p, entry, tuple(segs), symbols, text)

    def read(self, addr: int, size: int) -> bytes | None:
        """``size`` bytes at ``addr`` from the loaded contents (None if not all there)."""
        for seg in self.segments:
            if seg.vaddr <= addr and addr + size <= seg.vaddr + len(seg.data):
                return seg.data[addr - seg.vaddr:addr - seg.vaddr + size]
        return None

    def _check_constants(self, data: bytes) -> None:
        expected = expected_constants_hash()
        if expected is None:
            return                       # not in the source tree: nothing to compare with
        sym = self.symbols.get(HASH_SYMBOL)
        if sym is None:
            raise UserError(f"firmware ELF {self.path} carries no constants hash (symbol "
                            f"{HASH_SYMBOL}: not built by firmware/build.py of this tree, or "
                            "before it embedded one): run make firmware")
        if self.read(sym[0], 16) != expected.encode():
            raise UserError(f"firmware ELF {self.path} is stale (built from other constants "
                            "than the Python definitions of this tree): run make firmware")


def _bad(p: Path, what: str) -> UserError:
    return UserError(f"firmware ELF {p} {what}")


def _header(p: Path, data: bytes) -> tuple[int, tuple[int, int, int], tuple[int, int, int, int]]:
    """The ELF header checked: (entry, (phoff, phentsize, phnum), (shoff, shentsize, shnum,
    shstrndx)); UserError for another kind of file, struct.error when truncated."""
    if data[:4] != b"\x7fELF":
        raise _bad(p, "is not an ELF file; give the linked firmware (make firmware builds "
                   "build/firmware/snan-fw.elf)")
    if len(data) < 52:
        raise struct.error("header")
    if data[4] != 1 or data[5] != 1 or data[18] != 0xF3:
        raise _bad(p, "is not a 32-bit little-endian RISC-V ELF; the MIK32 runs RV32IMC "
                   "(make firmware)")
    e_type, = struct.unpack_from("<H", data, 0x10)
    if e_type != 2:
        kind = {1: "a relocatable object (.o)", 3: "a shared object"}.get(e_type,
                                                                          f"type {e_type}")
        raise _bad(p, f"is {kind}, not an executable; link it with firmware/link.ld "
                   "(make firmware)")
    entry, phoff, shoff = struct.unpack_from("<III", data, 0x18)
    phentsize, phnum, shentsize, shnum, shstrndx = struct.unpack_from("<HHHHH", data, 0x2A)
    for off, size, n in ((phoff, phentsize, phnum), (shoff, shentsize, shnum)):
        if n and off + size * n > len(data):
            raise struct.error("tables")
    return entry, (phoff, phentsize, phnum), (shoff, shentsize, shnum, shstrndx)


def _segments(p: Path, data: bytes, phoff: int, phentsize: int, phnum: int) -> list[Segment]:
    """The loadable segments, each checked to lie in the MIK32's flash (load address) and in
    its flash or RAM (run address)."""
    segs = []
    for i in range(phnum):
        ptype, off, vaddr, paddr, filesz, memsz, flags, _ = struct.unpack_from(
            "<IIIIIIII", data, phoff + i * phentsize)
        if ptype != 1 or not memsz:
            continue
        if off + filesz > len(data):
            raise struct.error("segment")
        if filesz and not _inside(paddr, filesz, FLASH):
            raise _bad(p, f"has a segment loaded at 0x{paddr:08x} ({filesz} B) outside the "
                       f"MIK32's SPIFI flash (0x{FLASH[0]:08x}, {FLASH[1] >> 20} MB); link "
                       "it with firmware/link.ld (make firmware)")
        if not (_inside(vaddr, memsz, FLASH) or _inside(vaddr, memsz, RAM)):
            raise _bad(p, f"has a segment at 0x{vaddr:08x} ({memsz} B) outside the MIK32's "
                       f"flash and its 16 KB RAM at 0x{RAM[0]:08x}; link it with "
                       "firmware/link.ld (make firmware)")
        segs.append(Segment(paddr, vaddr, data[off:off + filesz], memsz, flags))
    return segs


def _sections(data: bytes, shoff: int, shentsize: int, shnum: int,
              shstrndx: int) -> tuple[tuple[int, bytes], dict[str, tuple[int, int]]]:
    """(.text as (address, bytes), symbols name -> (address, size)) from the section
    headers; struct.error when a table points past the end of the file."""
    sh = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    shstr = sh[shstrndx][4] if shnum and shstrndx < shnum else 0
    text = (0, b"")
    symbols: dict[str, tuple[int, int]] = {}
    for s in sh:
        sname = _c_string(data, shstr + s[0])
        if sname == ".text":
            if s[1] != 8 and s[4] + s[5] > len(data):          # not NOBITS
                raise struct.error(".text")
            text = (s[3], data[s[4]:s[4] + s[5]])
        if s[1] == 2:                                  # SHT_SYMTAB
            if s[6] >= len(sh) or s[4] + s[5] > len(data):
                raise struct.error("symtab")
            _symbols(data, s, sh[s[6]][4], symbols)
    return text, symbols


def _symbols(data: bytes, symtab: tuple[int, ...], strtab: int,
             symbols: dict[str, tuple[int, int]]) -> None:
    for k in range(symtab[5] // 16):
        st_name, value, size, _info, _o, _shndx = struct.unpack_from(
            "<IIIBBH", data, symtab[4] + 16 * k)
        if st_name:
            symbols[_c_string(data, strtab + st_name)] = (value, size)


def _c_string(data: bytes, off: int) -> str:
    end = data.find(b"\0", off)
    if off >= len(data) or end < 0:
        raise struct.error("string table")
    return data[off:end].decode(errors="replace")


def _inside(addr: int, size: int, region: tuple[int, int]) -> bool:
    return region[0] <= addr and addr + size <= region[0] + region[1]


def expected_constants_hash() -> str | None:
    """The constants hash an ELF built from this tree carries (``firmware/gen_constants.py``,
    loaded from the source tree; None when it is not there, e.g. an installed wheel)."""
    global _expected_hash
    if _expected_hash is None and _GEN_CONSTANTS.is_file():
        spec = importlib.util.spec_from_file_location("_snan_gen_constants", _GEN_CONSTANTS)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _expected_hash = str(module.expected_hash())
    return _expected_hash
