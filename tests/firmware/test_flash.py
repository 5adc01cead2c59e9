"""``snan-hil flash`` (lab/flashing.py) with a stand-in for the vendor's uploader: the image is
checked before anything is written, the uploader gets the HEX and the options its README
documents, a missing or failing uploader is one line, and after flashing the board's INFO is
checked (here: the emulator running the same ELF on the instruction-level MCU)."""

from __future__ import annotations

import json
import stat

import pytest

from snan_hil.firmware_emu.fw_image import FirmwareImage, default_elf_path
from snan_hil.lab.flashing import check_image, intel_hex
from snan_hil.tools import cli

pytestmark = pytest.mark.skipif(not default_elf_path().is_file(),
                                reason="firmware ELF not built ('make firmware')")

STAND_IN = """\
import json, shutil, sys
log, code = {log!r}, {code}
shutil.copy(sys.argv[1], log + ".hex")
json.dump(sys.argv[1:], open(log, "w"))
if code:
    print("Error: no device found (JTAG adapter not connected)", file=sys.stderr)
sys.exit(code)
"""


@pytest.fixture
def env(tmp_path, monkeypatch):
    monkeypatch.delenv("SNAN_HIL_MIK32_UPLOADER", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))           # no uploader on the PATH
    return tmp_path


def _uploader(tmp_path, code=0):
    script = tmp_path / "mik32_upload.py"
    script.write_text(STAND_IN.format(log=str(tmp_path / "argv.json"), code=code))
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script


def _parse_hex(text: str) -> dict[int, int]:
    mem, upper = {}, 0
    for line in text.split():
        raw = bytes.fromhex(line[1:])
        assert sum(raw) & 0xFF == 0                             # checksum
        n, addr, kind, data = raw[0], raw[1] << 8 | raw[2], raw[3], raw[4:-1]
        assert len(data) == n
        if kind == 4:
            upper = int.from_bytes(data, "big") << 16
        elif kind == 0:
            for i, b in enumerate(data):
                mem[upper + addr + i] = b
    return mem


def test_the_image_checks_pass_on_the_built_firmware_and_the_hex_holds_its_flash_bytes():
    report = check_image(None)
    assert report.ok, report.first_problem()
    assert {c.name for c in report.checks} == {"constants hash", "flash size", "RAM",
                                               "load addresses", "entry point", "trap vector"}
    image = FirmwareImage.load()
    mem = _parse_hex(intel_hex(image))
    for seg in image.segments:
        if seg.data and seg.addr >= 0x8000_0000:
            assert bytes(mem[seg.addr + i] for i in range(len(seg.data))) == seg.data


def _patched(tmp_path, offset: int, data: bytes):
    elf = tmp_path / "bad.elf"
    raw = bytearray(default_elf_path().read_bytes())
    raw[offset:offset + len(data)] = data
    elf.write_bytes(bytes(raw))
    return elf


def test_a_bad_image_is_refused_before_the_uploader_runs(env, capsys):
    up = _uploader(env)
    raw = default_elf_path().read_bytes()
    image = FirmwareImage.load()
    # another constants hash (as an ELF built from other Python definitions)
    addr = image.symbols["snan_constants_hash"][0]
    hash_at = raw.index(image.read(addr, 16))
    stale = _patched(env, hash_at, b"0" * 16)
    code = cli.main(["flash", "--elf", str(stale), "--uploader", str(up), "--port", "x"])
    assert code == 2 and "constants hash" in capsys.readouterr().err
    # an entry point that is not where the boot ROM jumps
    moved = _patched(env, 24, (0x8000_0004).to_bytes(4, "little"))
    code = cli.main(["flash", "--elf", str(moved), "--uploader", str(up), "--port", "x"])
    err = capsys.readouterr().err
    assert code == 2 and "entry point" in err and "nothing was written" in err
    assert not (env / "argv.json").exists()


def test_no_uploader_is_one_line_and_check_only_needs_none(env, capsys):
    assert cli.main(["flash", "--port", "/dev/ttyUSB9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "uploader is not installed" in err[0]
    assert cli.main(["flash", "--check-only", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["image"]["ok"] and out["uploader"] is None


def test_a_failing_uploader_is_one_line_naming_its_error(env, capsys):
    up = _uploader(env, code=1)
    assert cli.main(["flash", "--uploader", str(up), "--port", "/dev/ttyUSB9"]) == 2
    err = capsys.readouterr().err
    assert "uploader failed (exit 1)" in err and "no device found" in err


def test_flash_runs_the_uploader_then_checks_the_boards_info(env, capsys, mcu):
    if mcu != "firmware":
        pytest.skip("the flashed board is the firmware MCU")
    up = _uploader(env)
    port = f"emu://?state={env}/chip.npz&mcu=firmware"
    code = cli.main(["flash", "--uploader", str(up), "--port", port, "--openocd", "/opt/oocd",
                     "--openocd-interface", "if.cfg", "--openocd-target", "mik32.cfg",
                     "--adapter-speed", "1000", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0, out
    argv = json.loads((env / "argv.json").read_text())
    assert argv[0].endswith(".hex") and "--run-openocd" in argv
    assert {"--boot-mode=spifi", "--mcu-type=MIK32V2", "--openocd-exec=/opt/oocd",
            "--openocd-interface=if.cfg", "--openocd-target=mik32.cfg",
            "--adapter-speed=1000"} <= set(argv)
    assert out["info"]["firmware_version"].startswith("snan-fw")
    assert out["boot_problems"] == []
    mem = _parse_hex((env / "argv.json.hex").read_text())
    assert min(mem) == 0x8000_0000
