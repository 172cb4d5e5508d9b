"""The Modules tab's calibration fields against viser's thread pool: a module picked fills the fields with its
calibration as the pick arrives, on viser's loop, so neither a value typed right after the pick is put back by it
(a fresh-clone run applied m3's zero as 0° where 10° had been typed) nor an Apply the pool runs first takes the last
module's values (the review of the first fix, which filled the fields on the pool and kept what was typed)."""

from __future__ import annotations

from types import SimpleNamespace

from .test_program_page import _arrives, _HeldPool, _tab


def test_a_value_typed_right_after_a_pick_is_kept_and_applied_whatever_order_the_pool_runs(studio, monkeypatch):
    app = studio.app
    panel = app.modules
    with panel._lock:
        panel._calibrations["m3"] = {"zero": 0.0, "direction": 1, "min": -90.0, "max": 90.0}
        panel._calibrations["m1"] = {"zero": 5.0, "direction": -1, "min": -30.0, "max": 30.0}
    with app.page.programmatic():
        panel.module.options = ["m1", "m3"]
        panel.module.value = "m1"
    panel._show_selected()
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, _tab(7))
    jobs: list[tuple] = []
    monkeypatch.setattr(panel, "_jobs", SimpleNamespace(put=jobs.append))
    _arrives(app, panel.low, -45.0)  # typed for m1, before the pick: m3's is shown over it
    _arrives(app, panel.module, "m3")
    _arrives(app, panel.zero, 10.0)  # typed right after the pick arrived
    _arrives(app, panel.apply_button, True)
    for fn, args in reversed(pool.held):  # the pool's worst order: Apply first, the pick's own callbacks last
        fn(*args)
    assert (panel.zero.value, panel.direction.value, panel.low.value, panel.high.value) == (10.0, "+1", -90.0, 90.0)
    assert jobs == [("apply", ("m3", {"zero": 10.0, "direction": 1, "min": -90.0, "max": 90.0}))], jobs
    _arrives(app, panel.module, "m1")  # a pick again: every field shows m1's (what was typed was for m3)
    assert (panel.zero.value, panel.direction.value, panel.low.value, panel.high.value) == (5.0, "-1", -30.0, 30.0)
