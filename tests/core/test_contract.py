"""The wire contract (contract/*.toml) is the one statement of the protocol's numbers: every generated copy — Python,
C headers, the protocol document's tables — is what it says, and an edit of the contract reaches all of them."""

from __future__ import annotations

import copy
import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _generator():
    spec = importlib.util.spec_from_file_location("contract_generate", ROOT / "contract" / "generate.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_no_generated_copy_of_the_contract_is_stale() -> None:
    stale = [str(p.relative_to(ROOT)) for p in _generator().stale()]
    assert stale == [], f"run `make contract`: {stale}"


def test_a_new_status_reaches_python_c_and_the_document(monkeypatch) -> None:
    generate = _generator()
    core, profile = generate.load()
    edited = copy.deepcopy(core)
    edited["status"].append({"id": 14, "name": "OVERHEATED", "raises": "RemoteError", "doc": "too hot to move"})
    edited["method"].append({"id": 12, "name": "CALIBRATE", "applies": "attribute", "request": "none",
                             "reply": "none", "writes": True})  # fmt: skip
    python = generate.python_core(edited)
    assert "    OVERHEATED = 14" in python and 'Status.OVERHEATED: "RemoteError"' in python
    assert "Method.CALIBRATE" in python.split("WRITES = ", 1)[1].split("\n", 1)[0]
    header = generate.c_core(edited)
    assert "ASM_S_OVERHEATED = 14" in header and "(1u << ASM_CALIBRATE)" in header
    document = generate.document((ROOT / "docs" / "protocol.md").read_text(), generate.doc_tables(edited, profile))
    assert "| 14 | OVERHEATED | too hot to move | `RemoteError` |" in document
    assert re.search(r"\| 12 \| CALIBRATE \|", document)


def test_the_generated_python_is_what_asm_py_uses() -> None:
    from asm_module._profile import CLASSES, PROFILE
    from asm_py import _contract, protocol
    from asm_py.canbus import ids
    from asm_py.classes import well_known

    assert protocol.Status is _contract.Status and protocol.Method is _contract.Method
    assert ids.Priority is _contract.Priority and ids.Dest is _contract.Dest
    assert dict(well_known()) == {**_contract.CORE_CLASSES, **CLASSES}
    assert all(spec.id == CLASSES[name] for name, spec in PROFILE.items())


def test_the_c_headers_carry_every_number_of_the_contract() -> None:
    generate = _generator()
    core, profile = generate.load()
    header = (ROOT / "firmware" / "include" / "asm" / "contract.h").read_text()
    for status in core["status"]:
        assert f"ASM_S_{status['name']} = {status['id']}" in header
    for method in core["method"]:
        assert f"ASM_{method['name']} = {method['id']}" in header
    profile_h = (ROOT / "firmware" / "include" / "asm" / "profile.h").read_text()
    for cls in profile["class"]:
        assert f"#define ASM_C_{cls['name'].upper().replace('.', '_')} {cls['id']:#04x}u" in profile_h


def test_hand_written_c_never_restates_a_contract_number() -> None:
    """The enums and class IDs live in the generated headers only (the twins it replaced were kept in step by the
    golden vectors alone)."""
    for path in (ROOT / "firmware").rglob("*.[ch]"):
        if path.name in ("contract.h", "profile.h"):
            continue
        text = path.read_text()
        assert not re.search(r"enum asm_(status|method|kind|dest_kind|frame_type|system)\s*\{", text), path
        assert not re.search(r"\bC_(GOAL|TABLE|SIGNAL|ESTOP)\s*=", text), path


def test_a_document_marker_without_a_table_is_an_error() -> None:
    generate = _generator()
    with pytest.raises(KeyError, match="nonsense"):
        generate.document("<!-- contract:nonsense -->\nx\n<!-- /contract -->", {})


@pytest.mark.parametrize(
    ("table", "entry", "words"),
    [
        ("method", {"id": 16, "name": "TOO_FAR"}, "outside 0..15"),
        ("method", {"id": 3, "name": "TWICE"}, "used twice"),
        ("status", {"id": 300, "name": "HUGE"}, "outside 0..255"),
        ("kind", {"id": 4, "name": "FIFTH"}, "outside 0..3"),
        ("codec_tag", {"tag": 0x01, "name": "AGAIN"}, "used twice"),
    ],
)
def test_a_contract_the_wire_cannot_carry_is_refused_before_anything_is_written(table, entry, words) -> None:
    generate = _generator()
    core, profile = generate.load()
    edited = copy.deepcopy(core)
    edited[table].append({**edited[table][0], **entry})
    with pytest.raises(ValueError, match=words):
        generate.check(edited, profile)


def test_the_reserved_method_row_follows_the_methods() -> None:
    generate = _generator()
    core, profile = generate.load()
    assert generate._reserved(core) == [["12-15", "reserved", "", "", "a node answers UNSUPPORTED"]]
    edited = copy.deepcopy(core)
    edited["method"].append({**core["method"][0], "id": 12, "name": "ECHO"})
    assert generate._reserved(edited)[0][0] == "13-15"
    edited["method"] += [{**core["method"][0], "id": k, "name": f"M{k}"} for k in (13, 14, 15)]
    assert generate._reserved(edited) == []


def test_the_client_exceptions_and_the_zenoh_keys_are_the_contracts() -> None:
    """asm_py binds the contract's ``raises`` names and key patterns; it restates neither."""
    from asm_py import keys
    from asm_py._contract import STATUS_RAISES, ZENOH_KEYS
    from asm_py.protocol import Message, Status
    from asm_py.status import raise_for_status

    for status, name in STATUS_RAISES.items():
        reply = Message(kind=2, method=0, txn=0, status=int(status), object_id=0, data=b"x")
        with pytest.raises(Exception) as caught:
            raise_for_status(reply, "call")
        assert type(caught.value).__name__ == name, status
    robot = keys.RobotKeys("r1")
    assert robot.requests("m1", "~t") == ZENOH_KEYS["requests"].format(robot="r1", node="m1", source="~t")
    assert robot.alive("m1", "s") == ZENOH_KEYS["alive"].format(robot="r1", node="m1", session="s")
    assert keys.lab_estop("x") == ZENOH_KEYS["lab_estop"].format(source="x")
    assert Status.OK not in STATUS_RAISES


def test_a_firmware_build_regenerates_only_the_c_headers(tmp_path, monkeypatch, capsys) -> None:
    """The C build runs the generator for its headers; the Python and the doc stay `make contract`'s (so a
    forgotten `make contract` is caught by the stale test, not silently fixed by a build)."""
    generate = _generator()
    header, python = tmp_path / "contract.h", tmp_path / "_contract.py"
    monkeypatch.setattr(generate, "outputs", lambda: {header: "/* new */\n", python: "NEW = 1\n"})
    monkeypatch.setattr(generate, "ROOT", tmp_path)
    assert generate.main(["--headers"]) == 0
    assert header.read_text() == "/* new */\n" and not python.exists()
    assert "--headers" in (ROOT / "asm_module" / "firmware_build.py").read_text()  # what the build runs
