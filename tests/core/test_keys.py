"""The Zenoh key space (asm_py.keys) against its golden vectors, and hostile addresses refused."""

from __future__ import annotations

import json

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from asm_py.keys import ALL_ROBOTS, RobotKeys, concrete, lab_estop, parse_address

from ..helpers import VECTORS

KEY_VECTORS = json.loads((VECTORS / "keys.json").read_text())


@pytest.mark.parametrize("case", KEY_VECTORS["keys"], ids=lambda c: f"{c['what']}:{c['key']}")
def test_every_golden_key_is_built_as_specified(case: dict) -> None:
    if case["what"] == "lab_estop":
        built = lab_estop(*case["args"])
    else:
        built = getattr(RobotKeys(case["robot"]), case["what"])(*case["args"])
    assert built == case["key"]
    zenoh.KeyExpr(built)  # and Zenoh takes it as a key expression


@pytest.mark.parametrize("case", KEY_VECTORS["addresses"], ids=lambda c: c["address"])
def test_addresses_name_a_robot_a_node_and_its_role(case: dict) -> None:
    address = parse_address(case["address"])
    assert (address.robot, address.name, address.tool, address.segment) == (
        case["robot"],
        case["name"],
        case["tool"],
        case["segment"],
    )
    assert str(address) == case["address"]


@pytest.mark.parametrize("bad", KEY_VECTORS["bad_addresses"])
def test_a_malformed_address_is_refused(bad: str) -> None:
    with pytest.raises(ValueError):
        parse_address(bad)


@given(st.text(max_size=80) | st.binary(max_size=20).map(lambda b: b.decode("latin-1")))
def test_any_text_is_an_address_or_a_value_error_never_a_wildcard_key(text: str) -> None:
    try:
        address = parse_address(text)
    except ValueError:
        return
    key = RobotKeys(address.robot or "r").requests(address.segment, "~me")
    assert "*" not in key and "$" not in key and "@" not in key.split("/")[2]


def test_verbatim_chunks_keep_wildcards_off_groups_estops_liveliness_and_the_lab() -> None:
    """A queryable of every node of robot a does not match a group, an e-stop, a liveliness key or the lab stop."""
    every_node = zenoh.KeyExpr(RobotKeys("a").requests("*", "*"))
    for key in (RobotKeys("a").group("all", "x"), RobotKeys("a").estop("x"), RobotKeys("a").alive("m1", "z")):
        assert not every_node.intersects(zenoh.KeyExpr(key)), key
    assert not zenoh.KeyExpr("asm/*/**").intersects(zenoh.KeyExpr(lab_estop("x")))
    assert zenoh.KeyExpr(ALL_ROBOTS.robot_key("status")).intersects(zenoh.KeyExpr(RobotKeys("b").robot_key("status")))
    assert not zenoh.KeyExpr(RobotKeys("a").requests("m3")).intersects(zenoh.KeyExpr(RobotKeys("a").requests("~m3")))


def test_a_reply_key_is_always_concrete() -> None:
    assert concrete("~studio") == "~studio"
    assert concrete("*") == concrete("**") == concrete("$*") == "any"
