"""The Modules tab's calibration fields against viser's thread pool: a module picked fills the fields with its
calibration in a callback viser runs later on its pool, so a value typed right after the pick must not be put back
by it (a fresh-clone run applied m3's zero as 0° where 10° had been typed)."""

from __future__ import annotations

from .test_program_page import _arrives, _HeldPool, _tab


def test_a_field_typed_right_after_a_pick_keeps_its_value_when_the_picks_callback_runs_late(studio, monkeypatch):
    app = studio.app
    panel = app.modules
    with panel._lock:
        panel._calibrations["m3"] = {"zero": 0.0, "direction": 1, "min": -90.0, "max": 90.0}
        panel._calibrations["m1"] = {"zero": 5.0, "direction": -1, "min": -30.0, "max": 30.0}
    with app.page.programmatic():
        panel.module.options = ["m1", "m3"]
        panel.module.value = "m1"
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, _tab(7))
    _arrives(app, panel.low, -45.0)  # typed for m1, before the pick: m3's is shown over it
    _arrives(app, panel.module, "m3")
    _arrives(app, panel.zero, 10.0)  # typed right after the pick arrived, before its callback ran
    for fn, args in pool.held:
        fn(*args)
    assert (panel.zero.value, panel.direction.value, panel.low.value, panel.high.value) == (10.0, "+1", -90.0, 90.0)
    pool.held.clear()
    _arrives(app, panel.module, "m1")  # a pick again: every field shows m1's (what was typed was for m3)
    for fn, args in pool.held:
        fn(*args)
    assert (panel.zero.value, panel.direction.value, panel.low.value, panel.high.value) == (5.0, "-1", -30.0, 30.0)
