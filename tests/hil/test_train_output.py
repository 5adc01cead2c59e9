"""``train -o`` never silently replaces other training (docs/outputs.md): a trained weights
file is replaced without ``--force`` only when it holds the very training requested."""

import numpy as np

from snan_hil.tools import cli

SHORT = ["--grid", "6", "--cycles", "2", "--set", "grid.max_steps=15", "--json"]


def test_train_refuses_to_replace_other_training_without_force(tmp_path, capsys):
    out = tmp_path / "w.npz"
    assert cli.main(["train", "--sets", "2", "-o", str(out), *SHORT]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    for other in (["--sets", "1"], ["--sets", "2", "--seed", "5"],
                  ["--sets", "2", "--set", "astro.tau_ca_s=4"]):
        assert cli.main(["train", *other, "-o", str(out), *SHORT]) == 2
        err = capsys.readouterr().err.strip()
        assert "holds other trained weights (2 set(s), seeds 1..2, 2 cycles" in err, err
        assert "--force" in err and "\n" not in err
        assert out.read_bytes() == before                 # untouched
    # the same training again: written again (deterministic: the same weights)
    w0 = np.load(out)["weights"]
    assert cli.main(["train", "--sets", "2", "-o", str(out), *SHORT]) == 0
    assert np.array_equal(np.load(out)["weights"], w0)
    # --force replaces other training
    assert cli.main(["train", "--sets", "1", "-o", str(out), "--force", *SHORT]) == 0
    assert np.load(out)["weights"].shape[0] == 1
