"""experiment --json: per figure its files and headline numbers next to the paper's; the text
output prints them too (tools.headlines)."""

from __future__ import annotations

import json

from snan_hil.host.intervals import METHOD, paper_distance, paper_inside
from snan_hil.tools import cli
from snan_hil.tools.headlines import headlines


def test_experiment_json_and_headline_table(tmp_path, capsys):
    out = tmp_path / "res"
    assert cli.main(["experiment", "fig3", "--trials", "8", "--workers", "1", "--out", str(out),
                     "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    (fig,) = data["figures"]
    assert fig["figure"] == "fig3" and set(fig["files"]) == {"json", "csv", "png", "md"}
    heads = {(h["condition"]["astro"], h["quantity"]): h for h in fig["headlines"]}
    assert heads[(False, "success_rate")]["paper"] == 0.631
    assert heads[(True, "median_steps")]["paper"] == 4.0
    written = json.loads((out / "fig3" / "fig3.json").read_text())
    main = {r["astro"]: r for r in written["rows"] if r["part"] == "main"}
    assert heads[(True, "success_rate")]["ours"] == main[True]["success_rate"]
    assert heads[(False, "median_steps")]["ours"] == main[False]["median_steps"]
    for (astro, q), h in heads.items():          # every headline: our interval, paper inside
        assert h["ours_ci"] == main[astro][f"{q}_ci"]
        assert h["paper_inside"] == paper_inside(h["paper"], h["ours_ci"])
        assert h["paper_distance"] == paper_distance(h["paper"], h["ours_ci"])
        assert h["ci_method"] == METHOD[q]
    # text mode prints the same numbers (the same run again, from its checkpoint)
    assert cli.main(["experiment", "fig3", "--trials", "8", "--workers", "1", "--out",
                     str(out), "--resume"]) == 0
    text = capsys.readouterr().out
    assert "headline numbers" in text and "63.1 %" in text


def test_fig7_headlines_take_the_main_variant_at_the_first_and_last_cycle():
    rows = [{"variant": v, "grid": "3x3", "cycle": c, "test_median_steps": m,
             "test_success_rate": s}
            for v, c, m, s in (("main", 0, 9.0, 0.5), ("main", 20, 4.0, 0.97),
                               ("other", 0, 99.0, 0.1), ("other", 20, 99.0, 0.1))]
    got = headlines("fig7", {"paper": {"3x3": (10.0, 4.0, 0.58, 0.978)}}, rows)
    assert [(h["condition"]["cycle"], h["quantity"], h["ours"], h["paper"]) for h in got] == [
        (0, "median_steps", 9.0, 10.0), (0, "success_rate", 0.5, 0.58),
        (20, "median_steps", 4.0, 4.0), (20, "success_rate", 0.97, 0.978)]
    assert all(h["ours_ci"] is None and h["paper_inside"] is None for h in got)
    rows[0]["test_success_rate_ci"] = [0.4, 0.6]
    rows[0]["test_median_steps_ci"] = [7.0, 9.5]
    first = headlines("fig7", {"paper": {"3x3": (10.0, 4.0, 0.58, 0.978)}}, rows)[:2]
    assert [(h["paper_inside"], h["paper_distance"]) for h in first] == [(False, 0.5),
                                                                         (True, 0.0)]
