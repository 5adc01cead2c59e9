"""Results record what made them: the package version in the programming report, the mac
result, the cell-test result and the map (and the mac result its weights' source and seed)."""

from __future__ import annotations

import json

from snan_hil.tools import cli


def test_reports_carry_the_version(programmed_emu, capsys):
    from snan_hil import __version__
    d = programmed_emu
    assert json.loads((d / "chip.program-report.json").read_text())["version"] == __version__
    assert cli.main(["mac", "--port", "emu", "--weights", "random", "--grid", "3", "--seed",
                     "2", "--vectors", "5", "--out", str(d / "mac"), "--json"]) == 0
    capsys.readouterr()
    mac = json.loads((d / "mac" / "mac.json").read_text())
    assert mac["version"] == __version__
    assert mac["weights"] == {"source": "random", "weights": "random", "path": "random",
                              "grid": [3, 3], "seed": 2}
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "31,0", "-o",
                     str(d / "c.json"), "--json"]) == 0
    capsys.readouterr()
    assert json.loads((d / "c.json").read_text())["version"] == __version__
    assert cli.main(["map", "--port", "emu", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["version"] == __version__
