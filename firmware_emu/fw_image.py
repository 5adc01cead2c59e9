"""The built firmware ELF: where it is, and its loadable segments.

``default_elf_path()`` is ``build/firmware/snan-fw.elf`` in the source tree (``make firmware``
builds it), or ``$SNAN_HIL_FIRMWARE_ELF``. A missing file is one :class:`UserError` line that
says how to build it.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

from snan_hil.errors import UserError

ELF_ENV = "SNAN_HIL_FIRMWARE_ELF"
_ROOT = Path(__file__).resolve().parent.parent


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


@dataclass(frozen=True)
class FirmwareImage:
    path: Path
    entry: int
    segments: tuple[Segment, ...]
    symbols: dict[str, tuple[int, int]]     # name -> (address, size)
    text: tuple[int, bytes]                  # (address, bytes) of .text

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "FirmwareImage":
        p = Path(path) if path is not None else default_elf_path()
        if not p.is_file():
            raise UserError(f"firmware ELF {p} not found; build it with 'make firmware' (it "
                            f"needs the [firmware] extra: pip install -e '.[firmware]'), or set "
                            f"{ELF_ENV}")
        data = p.read_bytes()
        if data[:4] != b"\x7fELF" or data[4] != 1 or data[18] != 0xF3:
            raise UserError(f"{p} is not a 32-bit RISC-V ELF file; rebuild with 'make firmware'")
        entry, phoff, shoff = struct.unpack_from("<III", data, 0x18)
        phentsize, phnum, shentsize, shnum, shstrndx = struct.unpack_from("<HHHHH", data, 0x2A)
        segs = []
        for i in range(phnum):
            ptype, off, vaddr, paddr, filesz, memsz, flags, _ = struct.unpack_from(
                "<IIIIIIII", data, phoff + i * phentsize)
            if ptype == 1:
                segs.append(Segment(paddr, vaddr, data[off:off + filesz], memsz, flags))
        sh = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
        shstr = sh[shstrndx][4]

        def name(off: int) -> str:
            return data[off:data.index(b"\0", off)].decode()

        text = (0, b"")
        symbols: dict[str, tuple[int, int]] = {}
        for s in sh:
            sname = name(shstr + s[0])
            if sname == ".text":
                text = (s[3], data[s[4]:s[4] + s[5]])
            if s[1] == 2:                                  # SHT_SYMTAB
                strtab = sh[s[6]][4]
                for k in range(s[5] // 16):
                    st_name, value, size, _info, _o, _shndx = struct.unpack_from(
                        "<IIIBBH", data, s[4] + 16 * k)
                    if st_name:
                        symbols[name(strtab + st_name)] = (value, size)
        return cls(p, entry, tuple(segs), symbols, text)
