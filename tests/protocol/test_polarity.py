"""One polarity type end to end: the CLI parses words into it; the layers refuse strings."""

import pytest

from snan_hil.crossbar_model import CrossbarArray
from snan_hil.common.polarity import Polarity
from snan_hil.protocol import messages as m


def test_parse_accepts_either_case_and_names_the_choices():
    assert Polarity.parse("set") is Polarity.SET
    assert Polarity.parse(" RESET ") is Polarity.RESET
    with pytest.raises(ValueError, match="SET or RESET"):
        Polarity.parse("up")


def test_wire_numbering_is_the_legacy_sign_field():
    assert (int(Polarity.RESET), int(Polarity.SET)) == (0, 1)
    assert m.Polarity is Polarity
    req = m.WritePulse(1, 2, Polarity.RESET, 300, 100, 0)
    assert m.WritePulse.decode(req.encode()).polarity is Polarity.RESET


def test_crossbar_refuses_a_polarity_string():
    a = CrossbarArray(seed=0)
    with pytest.raises(ValueError, match="Polarity"):
        a.apply_pulse(0, 0, 1.0, "SET", 1e-4)
