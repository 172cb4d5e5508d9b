"""What the name-claim tests share: sessions with the Zenoh IDs they are given (so who is "greater" is known), and a
first look made blind, as when a rival's token had not reached a session yet."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

GREATER, LESSER = "f0f0", "1f1f"


def config_with_id(tmp_path: Path, zid: str) -> str:
    path = tmp_path / f"{zid}.json5"
    path.write_text(json.dumps({"id": zid}))
    return str(path)


def blind_first_look(monkeypatch: pytest.MonkeyPatch, cls: type, method: str, victim: Callable[[object], bool]) -> None:
    """``cls.method`` answers "nobody" to the first look of the session ``victim`` picks: its rival's token had
    not reached it yet."""
    real = getattr(cls, method)
    blinded: set[int] = set()

    def look(self: object, *args: object, **options: object) -> set[str]:
        if victim(self) and id(self) not in blinded:
            blinded.add(id(self))
            return set()
        return real(self, *args, **options)

    monkeypatch.setattr(cls, method, look)
