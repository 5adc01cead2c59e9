"""Speed/energy report (paper Fig. 10D method), the HIL config file, acceptance checks."""

import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.config import load_config
from snan_hil.host.hil.compare import acceptance
from snan_hil.host.hil.config import load_hil_config
from snan_hil.host.hil.report import speed_energy_table


def test_paper_method_reproduces_the_papers_numbers():
    rows = speed_energy_table(36)["rows"]
    cpu, xbar = rows[0], rows[1]
    # the paper: 64.4 us, 0.0029 J, 7.16e-5 decisions/us/mm2 for the CPU ...
    assert cpu["time_per_decision_us"] == pytest.approx(64.4, abs=0.1)
    assert cpu["energy_per_decision_j"] == pytest.approx(0.0029, rel=0.01)
    assert cpu["norm_speed_per_us_mm2"] == pytest.approx(7.16e-5, rel=0.005)
    # ... 3.23e-4 (4.5 times the CPU) and 56 nJ (51,739 times less) for the crossbar
    assert xbar["norm_speed_per_us_mm2"] == pytest.approx(3.23e-4, rel=0.005)
    assert xbar["speed_vs_cpu"] == pytest.approx(4.5, abs=0.05)
    assert xbar["energy_per_decision_j"] == pytest.approx(56e-9, rel=0.01)
    assert xbar["energy_gain_vs_cpu"] == pytest.approx(51739, rel=0.01)
    # operations scale with N^2: a 10x10 field costs (100/36)^2 times the 6x6 one
    assert speed_energy_table(100)["rows"][0]["time_per_decision_us"] == pytest.approx(
        cpu["time_per_decision_us"] * (100 / 36) ** 2)


def test_measured_rows_use_the_board_clock_without_uart():
    hw = {"decisions": 10, "spikes": 1500, "virtual_us": 2.0e6, "wire_us": 1.5e6,
          "energy_j": 4e-6, "baud": 115200}
    geo = {"spike_us": 550.0, "spike_energy_j": 1e-7, "read_v": 0.3}
    rows = speed_energy_table(36, hw=hw, geometry=geo,
                              sw={"decisions": 1000, "wall_s": 0.05})["rows"]
    assert len(rows) == 6
    g, board, with_uart, sw = rows[2], rows[3], rows[4], rows[5]
    assert g["time_per_decision_us"] == pytest.approx(550.0 * 12)
    assert g["energy_per_decision_j"] == pytest.approx(1.2e-6)
    assert board["time_per_decision_us"] == pytest.approx(5e4)      # (2.0 - 1.5) s / 10
    assert with_uart["time_per_decision_us"] == pytest.approx(2e5)
    assert board["energy_per_decision_j"] == pytest.approx(4e-7)
    assert board["norm_speed_per_us_mm2"] == pytest.approx(1 / 5e4 / 0.368)
    assert sw["time_per_decision_us"] == pytest.approx(50.0)
    for r in rows:
        assert r["method"] and r["source"]


def test_hil_config_derives_from_the_base_preset(tmp_path):
    hil = load_hil_config()
    base = load_config(preset=hil.base)
    assert (hil.model.grid.rows, hil.model.grid.cols) == (6, 6)
    assert (hil.task.start, hil.task.goal) == (18, 0)
    # everything not listed under `set` is the preset's
    assert hil.model.neuron == base.neuron and hil.model.synapse == base.synapse
    assert hil.model.stdp == base.stdp
    launch = hil.launch_config(astro=False)
    assert launch.stdp.mode == "off" and not launch.astro.enabled
    assert hil.train_config().astro.enabled
    assert load_hil_config(None, ["astro.tau_ca_s=3"]).model.astro.tau_ca_s == 3.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("base: snan-10x10\nset:\n  grid.nope: 3\n")
    with pytest.raises(UserError, match="grid.nope"):
        load_hil_config(bad)
    bad.write_text("base: snan-10x10\ntask:\n  start: x\n")
    with pytest.raises(UserError, match="task.start"):
        load_hil_config(bad)
    plain = tmp_path / "plain.yaml"                 # a plain SNAN config file works too
    plain.write_text("grid:\n  rows: 6\n  cols: 6\n")
    assert load_hil_config(plain).model.grid.rows == 6


def test_acceptance_checks():
    def s(m, m_all=None):
        return {"median_steps": m, "median_steps_all": m_all}
    acc = acceptance({"sw_noastro": s(14), "sw_astro": s(7), "hw_noastro": s(16),
                      "hw_astro": s(9)})
    assert acc["sw_astro_shortens"] and acc["hw_astro_shortens"]
    assert acc["hw_within_20pct_noastro"] and not acc["hw_within_20pct_astro"]
    assert acc["hw_vs_sw_astro"] == pytest.approx(9 / 7 - 1)
    assert acceptance({"sw_noastro": s(None), "sw_astro": s(7)})["sw_astro_shortens"] is None
    both = acceptance({"sw_noastro": s(7, 60), "sw_astro": s(7, 9), "hw_noastro": s(7, 100),
                       "hw_astro": s(7, 9)})
    assert not both["sw_astro_shortens"] and both["sw_astro_shortens_all"]
    assert both["hw_within_20pct_noastro"] and not both["hw_within_20pct_noastro_all"]


def test_acceptance_says_whether_astrocytes_shorten_beyond_the_intervals():
    def s(m, ci):
        return {"median_steps": m, "median_steps_all": m, "median_steps_ci": ci,
                "median_steps_all_ci": ci, "paper_inside": None}
    acc = acceptance({"sw_noastro": s(14, [12, 16]), "sw_astro": s(7, [6, 9]),
                      "hw_noastro": s(14, [10, 18]), "hw_astro": s(12, [8, 13])})
    assert acc["sw_astro_shortens"] and acc["sw_astro_shortens_ci"]
    assert acc["hw_astro_shortens"] and not acc["hw_astro_shortens_ci"]     # overlapping
    assert acc["sw_astro_shortens_ci_all"] and "paper_inside_sw_astro" in acc
    assert acceptance({"sw_noastro": s(14, None), "sw_astro": s(7, [6, 9])}
                      )["sw_astro_shortens_ci"] is None


def test_hil_config_values_stay_typed(tmp_path):
    f = tmp_path / "hil.yaml"
    f.write_text("base: snan-10x10\nset:\n  grid.rows: 6\n  grid.cols: 6\n"
                 "  astro.alpha_n_per_ms: 0.00001\n  grid.max_steps: 010\n"
                 "train_set:\n  stdp.a_plus: 1e-2\n")
    hil = load_hil_config(f)
    assert hil.model.astro.alpha_n_per_ms == 1e-5 and hil.model.grid.max_steps == 10
    assert hil.train_config().stdp.a_plus == 0.01
    assert load_hil_config(f, ["astro.alpha_n_per_ms=1e-3"]).model.astro.alpha_n_per_ms == 1e-3
    for text, fragment in [
        ("set:\n  astro.enabled: 'false'\n", "set: astro.enabled: expected true or false"),
        ("train_set:\n  stdp.nope: 1\n", "train_set: unknown config key stdp.nope"),
        ("task: {start: 1}\nextra: 1\n",
         "unknown config key extra (known: base, name, set, task, train_set)"),
    ]:
        f.write_text("base: snan-10x10\n" + text)
        with pytest.raises(UserError) as exc:
            load_hil_config(f)
        assert fragment in str(exc.value) and "\n" not in str(exc.value)


def test_the_ceiling_row_and_the_spikes_each_row_counts():
    """Issue 33: beside the paper's 700 us a spike (8.4 ms a decision of 12 spikes), the
    board's ceiling from the datasheet parts for this run's read plan, and every crossbar row's
    input spikes per decision and time per spike."""
    d = 10
    plan = {"decisions": d, "codes_read": 5000, "waits": 4000, "row_words": 300,
            "request_bytes": 300, "reply_bytes": 200, "conversions": 2}
    hw = {"decisions": d, "spikes": 1500, "requests": d, "virtual_us": 2.0e5, "wire_us": 6e4,
          "energy_j": 7e-6, "baud": 115200, "mode": "on_board", "plan": plan}
    rows = {r["implementation"]: r for r in speed_energy_table(36, hw=hw)["rows"]}
    paper = rows["crossbar, paper"]
    assert paper["spikes_per_decision"] == 12 and paper["time_per_spike_us"] == 700.0
    assert paper["time_per_decision_us"] == 8400.0
    board = rows["emu board, on-board window"]
    assert board["spikes_per_decision"] == 150
    assert board["time_per_spike_us"] == pytest.approx(1.4e4 / 150)
    assert "2 conversions a read" in board["method"]
    ceil = rows["board ceiling, datasheets"]
    # per decision 500 reads, 400 of them after a change: ADC (1 more conversion a read, the
    # 100 unchanged reads, one end frame) x 5 us; settling 400 x (16 + 8 bits at 15 MHz + 6 us)
    # plus 30 DAC words; the larger wire direction 30 bytes x 10 bits / 115200
    adc = (500 + 100 + 1) * 5.0
    dac = 400 * (16 / 15 + 8 / 15 + 6.0) + 30 * 16 / 15
    assert ceil["time_per_decision_us"] == pytest.approx(adc + dac)
    assert "ADC" in ceil["method"] and ceil["spikes_per_decision"] == 150
    assert ceil["time_per_decision_us"] < board["time_per_decision_us"]
    no_plan = {r["implementation"] for r in speed_energy_table(
        36, hw={k: v for k, v in hw.items() if k != "plan"})["rows"]}
    assert "board ceiling, datasheets" not in no_plan       # the standard reads: no plan stats


def test_the_ceiling_of_the_standard_reads_counts_the_dummy_and_the_averages():
    d = 10
    plan = {"decisions": d, "codes_read": 3000, "waits": 3000, "row_words": 3000,
            "request_bytes": 300, "reply_bytes": 200, "conversions": 0, "averages": 10}
    hw = {"decisions": d, "spikes": 1500, "requests": d, "virtual_us": 7.0e5, "wire_us": 6e4,
          "energy_j": 3e-5, "baud": 115200, "mode": "on_board", "plan": plan}
    rows = {r["implementation"]: r for r in speed_energy_table(36, hw=hw)["rows"]}
    ceil = rows["board ceiling, datasheets"]
    # 300 reads a decision, each a dummy and 10 conversions at 5 us: ADC-bound
    assert ceil["time_per_decision_us"] > 300 * 11 * 5.0
    assert "after a dummy" in ceil["method"] and "ADC" in ceil["method"]
    assert ceil["time_per_decision_us"] < rows["emu board, on-board window"][
        "time_per_decision_us"]


def test_interleaved_launches_give_only_the_board_clock_with_the_uart():
    """The UART overlaps the board's work: subtracting it would understate the board's time."""
    hw = {"decisions": 10, "spikes": 1500, "requests": 10, "virtual_us": 1.5e5, "wire_us": 6e4,
          "energy_j": 7e-6, "baud": 115200, "mode": "on_board", "interleaved": True}
    rows = {r["implementation"]: r for r in speed_energy_table(36, hw=hw)["rows"]}
    assert "emu board, on-board window" not in rows
    with_uart = rows["emu board on-board + UART"]
    assert with_uart["time_per_decision_us"] == pytest.approx(1.5e4)
    assert "interleaved" in with_uart["method"]
    assert "emu board, on-board window" in {r["implementation"] for r in speed_energy_table(
        36, hw={**hw, "interleaved": False})["rows"]}
