"""One rule for the cells of every command (tools/commands/_cells.py), and the fresh-user
defects of issue 24's plan / cells commands: each bad input one line, exit 2, nothing recorded,
nothing on stdout."""

from __future__ import annotations

import pytest

from snan_hil.common.errors import UserError
from snan_hil.tools import cli
from snan_hil.tools.commands._cells import one_cell, parse_cell_list, read_cell_file


def test_the_shared_parser_takes_spaces_and_semicolons_and_refuses_repeats():
    assert parse_cell_list(["0,0", "3, 5;4,5"], "--cells", 32, 8) == [(0, 0), (3, 5), (4, 5)]
    assert parse_cell_list("1,2;2,1", "--cells", 32, 8) == [(1, 2), (2, 1)]
    with pytest.raises(UserError, match=r"cell \(3,5\) is named twice"):
        parse_cell_list(["3,5", "4,5", "3,5"], "--cells", 32, 8)
    with pytest.raises(UserError, match="no cells given"):
        parse_cell_list(" ; ", "--cells", 32, 8)
    assert one_cell("3, 5", "--cell", 32, 8) == (3, 5)
    with pytest.raises(UserError, match="give one cell"):
        one_cell("3,5;4,5", "--cell", 32, 8)


def test_a_cell_file_with_no_cell_or_a_repeated_one_is_refused(tmp_path):
    header_only = tmp_path / "good.csv"
    header_only.write_text("row,col,verdict\n# nothing passed\n")
    with pytest.raises(UserError, match="no cells in the file"):
        read_cell_file(header_only, "--cells-file", 32, 8)
    twice = tmp_path / "twice.csv"
    twice.write_text("row,col\n1,1\n2,2\n1,1\n")
    with pytest.raises(UserError, match=r"\(1,1\) is named twice \(line 2 and line 4\)"):
        read_cell_file(twice, "--cells-file", 32, 8)



def test_a_cell_file_with_a_byte_order_mark_is_read(tmp_path):
    # found by a fresh-user pass: a spreadsheet's CSV (UTF-8 with BOM) was refused
    bom = tmp_path / "excel.csv"
    bom.write_bytes("row,col\r\n3,5\r\n4,5\r\n".encode("utf-8-sig"))
    assert read_cell_file(bom, "--cells-only", 32, 8) == [(3, 5), (4, 5)]
    bare = tmp_path / "bare.csv"
    bare.write_bytes("\ufeff3,5\n".encode())
    assert read_cell_file(bare, "--cells-file", 32, 8) == [(3, 5)]


@pytest.mark.parametrize("text, line, needle", [
    ("1,2\n1,2,3\n", 2, "3 field(s) where 2 fields (row,col) are expected"),
    ("1,2,3\n", 1, "3 field(s) where 2 fields (row,col) are expected"),
    ("row,col,verdict\n1,2,good\n3,4\n", 3, "2 field(s) where the header's 3 fields"),
    ("row,col\n1,2,3\n", 2, "3 field(s) where the header's 2 fields"),
])
def test_a_cell_file_line_with_the_wrong_number_of_fields_is_refused(tmp_path, text, line,
                                                                      needle):
    # found by a fresh-user pass: a header-less 1,2,3 line was read as the cell (1,2)
    f = tmp_path / "cells.csv"
    f.write_text(text)
    with pytest.raises(UserError) as exc:
        read_cell_file(f, "--cells-file", 32, 8)
    assert f"line {line}: {needle}" in str(exc.value)


CELL_CASES = [
    (["plan", "run", "set", "--cells", "1,1", "2,2", "1,1"], "named twice"),
    (["cells", "test", "--cells", "1,1", "1,1"], "named twice"),
    (["characterize", "--cells", "1,1;1,1"], "named twice"),
    (["read-cell", "--cell", "1,1;2,2"], "give one cell"),
    (["pulse", "--cell", "1,1 2,2", "--polarity", "set", "--amplitude", "0.8"],
     "give one cell"),
    (["plan", "run", "set", "--cells-file", "EMPTY"], "no cells in the file"),
    (["cells", "test", "--cells-file", "EMPTY"], "no cells in the file"),
]


@pytest.mark.parametrize("argv, needle", CELL_CASES)
def test_every_command_takes_cells_by_the_same_rule(emu, capsys, argv, needle):
    (emu / "empty.csv").write_text("row,col\n")
    argv = [str(emu / "empty.csv") if a == "EMPTY" else a for a in argv]
    assert cli.main([*argv, "--port", "emu"]) == 2
    out = capsys.readouterr()
    assert needle in out.err and len(out.err.strip().splitlines()) == 1 and out.out == ""
    assert not (emu / "chip.npz").exists() and not list(emu.glob("*.sqlite"))   # nothing ran


@pytest.mark.parametrize("opt", ["--csv", "-o"])
def test_a_dry_run_refuses_an_output_it_would_not_write(emu, tmp_path, capsys, opt):
    target = tmp_path / "out.file"
    assert cli.main(["plan", "run", "set", "--cells", "1,1", "--dry-run", opt,
                     str(target)]) == 2
    out = capsys.readouterr()
    assert f"--dry-run sends nothing, so {opt} would get no result" in out.err
    assert out.out == "" and not target.exists()


def test_the_no_history_message_names_no_partial_list(emu, capsys):
    assert cli.main(["history", "--port", "emu", "--history", str(emu / "none.sqlite")]) == 2
    err = capsys.readouterr().err
    assert "no history database" in err and "--record off" in err
    assert "program-weights" not in err                 # no hand-kept list of commands


@pytest.mark.parametrize("opt, force", [("--bad-csv", []), ("--good-csv", ["--force"])])
def test_a_cell_list_read_is_never_written_over(emu, capsys, opt, force):
    # found by a fresh-user pass: cells test --cells-file b.csv --bad-csv b.csv rewrote its input
    cells = emu / "b3.csv"
    cells.write_text("row,col\n1,1\n2,2\n3,3\n")
    before = cells.read_bytes()
    assert cli.main(["cells", "test", "--port", "emu", "--cells-file", str(cells),
                     "--ratio-above", "1.1", opt, str(cells), *force]) == 2
    out = capsys.readouterr()
    assert "is also an input of this command (--cells-file" in out.err
    assert len(out.err.strip().splitlines()) == 1 and out.out == ""
    assert cells.read_bytes() == before
    assert not (emu / "chip.npz").exists()                            # nothing ran
