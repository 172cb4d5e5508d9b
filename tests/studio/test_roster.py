"""The Monitor's roster of nodes: a node dropped on purpose (a board renumbered, the ID a wiggle lent it) is not
shown lost, even when discovery's news of it comes late."""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace

import pytest

from web import monitor
from web.monitor import Roster

pytestmark = pytest.mark.timeout(30)


class FakeNode:
    """Discovery only: the test says who joins and leaves."""

    def __init__(self) -> None:
        self.transport = SimpleNamespace(address="~studio")
        self.changed: Callable[[str, bool], None] | None = None

    def discover(self) -> list[str]:
        return []

    def on_discovery(self, callback: Callable[[str, bool], None]) -> Callable[[], None]:
        self.changed = callback
        return lambda: None


def test_a_forgotten_node_is_not_brought_back_by_late_news_but_a_new_one_of_its_name_is(monkeypatch) -> None:
    clock = [100.0]
    monkeypatch.setattr(monitor.time, "monotonic", lambda: clock[0])
    node = FakeNode()
    roster = Roster(node)  # type: ignore[arg-type]
    assert node.changed is not None
    node.changed("m199", True)
    assert [name for name, _, _ in roster.rows()] == ["m199"]
    roster.forget(["m199"])
    node.changed("m199", True)  # a heartbeat from before it went, reported after the forget
    node.changed("m199", False)  # and its loss
    assert roster.rows() == []
    clock[0] += monitor.FORGET_GRACE + 1
    node.changed("m199", True)  # a board lent that ID again later: shown
    assert [(name, alive) for name, alive, _ in roster.rows()] == [("m199", True)]


def test_the_lost_nodes_are_listed_and_forgotten_on_request() -> None:
    # Issue 28's second review: an ID given by another tool and then erased stayed LOST on the Monitor for good.
    from web.monitor_panel import MonitorPanel

    node = FakeNode()
    roster = Roster(node)  # type: ignore[arg-type]
    assert node.changed is not None
    for name, alive in (("m1", True), ("m9", True), ("m9", False), ("m3", True), ("m3", False)):
        node.changed(name, alive)
    assert roster.lost() == ["m3", "m9"]
    emitted: list[tuple[str, list[str]]] = []

    def forget(names: list[str]) -> None:
        roster.forget(names)

    panel = SimpleNamespace(page=SimpleNamespace(robot=SimpleNamespace(roster=roster, forget=forget),
                                                 emit=lambda event, names: emitted.append((event, names))))  # fmt: skip
    assert MonitorPanel.forget_lost(panel) == ["m3", "m9"]  # type: ignore[arg-type]
    assert [name for name, _, _ in roster.rows()] == ["m1"] and emitted == [("modules_removed", ["m3", "m9"])]
