"""The legacy line-protocol conformance vectors (conformance/v1/legacy): the legacy emulator
reproduces every one of them, their portable expectations hold, and the data (and the doc table
made from it) is what the generator makes today."""

import importlib.util
import json
from pathlib import Path

import pytest

from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.protocol.legacy_codec import parse_reply

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "conformance" / "v1" / "legacy"
FILES = sorted(VECTORS.glob("*.jsonl"))


def _generator():
    spec = importlib.util.spec_from_file_location("legacy_vectors", VECTORS / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load(path: Path) -> tuple[dict, list[dict]]:
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    return lines[0], lines[1:]


def meets(vector: dict) -> bool:
    """Does ``out`` do what ``expect`` says any implementation must do?"""
    out, kind = vector["out"], vector["expect"]
    if kind == "silence":
        return out == ""
    if kind == "info":
        return out.endswith("\n") and out.count("\n") == 1 and len(out) > 1
    lines = out.splitlines(keepends=True)
    if not all(line.endswith("\n") for line in lines):
        return False
    if kind == "refusal":
        return lines == [f"-{vector['code']},{vector['id']}\n"]
    ids = vector["ids"] if kind == "replies" else [vector["id"]]
    if len(lines) != len(ids):
        return False
    replies = [parse_reply(line) for line in lines]
    return [r.id for r in replies] == ids and all(0 <= r.adc <= 16383 for r in replies)


def test_the_sessions_exist_and_cover_every_kind_of_expectation():
    names = {p.name for p in FILES}
    assert names == {"existing-firmware.jsonl", "refusals-extension.jsonl"}
    kinds = {v["expect"] for p in FILES for v in load(p)[1]}
    assert kinds == {"reply", "replies", "info", "silence", "refusal"}


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_the_legacy_emulator_reproduces_every_vector(path):
    head, vectors = load(path)
    assert head["format"] == "snan-hil-legacy-vectors/1"
    emu = Emulator(None, head["chip_seed"], protocol="legacy",
                   legacy_refusals=head["refusals"])
    try:
        for k, v in enumerate(vectors):
            assert meets(v), (k, v)
            out = emu.feed(v["in"].encode("ascii")).decode("ascii")
            assert out == v["out"], (k, v["in"], out, v["out"])
    finally:
        emu.close()


def test_the_vectors_and_the_doc_table_are_up_to_date(capsys):
    gen = _generator()
    assert gen.main(["--check"]) == 0, capsys.readouterr().err
    for path in FILES:
        assert path.read_text() == gen.render(path.name)
    doc = (ROOT / "docs" / "protocol.md").read_text()
    assert gen.doc_table() in doc


def test_a_stale_vector_is_noticed(tmp_path, monkeypatch):
    gen = _generator()
    monkeypatch.setattr(gen, "HERE", tmp_path)
    doc = tmp_path / "protocol.md"
    doc.write_text((ROOT / "docs" / "protocol.md").read_text())
    monkeypatch.setattr(gen, "DOC", doc)
    for path in FILES:
        (tmp_path / path.name).write_text(path.read_text().replace("1472,0", "1473,0"))
    assert gen.main(["--check"]) == 1
    assert gen.main([]) == 0 and gen.main(["--check"]) == 0
