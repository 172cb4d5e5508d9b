"""States over time: what the control table cannot show for an event-driven or one-shot gait.

A timed gait repeats one period, so the control table (web/control_table.py) draws it once. A gait whose states wait
for a contact, a neighbour or a signal, or that runs once and ends, has no period: its table was blank. This draws
instead what the preview's run did — modules down, simulated time across a fixed window, colour = the state each
module was in (grey once its gait no longer runs) — with a black line where a one-shot program ended. Rendered with
numpy alone, like the control table (viser sends it as a PNG).
"""

from __future__ import annotations

import numpy as np

from .control_table import CELL_HEIGHT, FRAME
from .monitor import PALETTE

WINDOW_SECONDS = 20.0
"""Simulated seconds across the picture: the last 20 s of the run up to the frame shown."""
COLUMNS = 200
CELL_WIDTH = 3
STOPPED = np.array([200, 200, 200], dtype=np.uint8)
"""A module whose gait does not run (a one-shot program that ended)."""
NOTHING = np.array([255, 255, 255], dtype=np.uint8)
"""Time not run yet (the window reaches past the frame shown)."""
ENDED = np.array([0, 0, 0], dtype=np.uint8)
"""The line where a one-shot program ended: black, unlike any state's colour."""
TICK = np.array([90, 90, 90], dtype=np.uint8)


def state_colour(state: int) -> np.ndarray:
    """The colour of 0-based state ``state`` (the plots' palette, in turn)."""
    code = PALETTE[state % len(PALETTE)]
    return np.array([int(code[k : k + 2], 16) for k in (1, 3, 5)], dtype=np.uint8)


def window(times: np.ndarray) -> tuple[float, float]:
    """The seconds the picture spans for a run whose frames are at ``times``: WINDOW_SECONDS from the first frame,
    or up to the newest once the run is longer."""
    if not len(times):
        return 0.0, WINDOW_SECONDS
    start = max(float(times[0]), float(times[-1]) - WINDOW_SECONDS)
    return start, start + WINDOW_SECONDS


def state_timeline(times: np.ndarray, states: np.ndarray, *, ended_at: float | None = None,
                   selected: int | None = None) -> np.ndarray:  # fmt: skip
    """The picture (H, W, 3) of ``states`` (n frames × modules, -1 where a gait did not run) at ``times`` (n,
    ascending); ``ended_at`` the time a one-shot program ended (a black line), ``selected`` a 0-based module row
    (framed). Each column shows the state at its time (the newest frame at or before it); a second tick is drawn
    at the foot of the picture every second."""
    states = np.asarray(states, dtype=int)
    times = np.asarray(times, dtype=float)
    if states.ndim != 2 or not states.size or len(times) != len(states):
        return np.full((CELL_HEIGHT, CELL_WIDTH, 3), 255, dtype=np.uint8)
    modules = states.shape[1]
    start, end = window(times)
    at = start + (np.arange(COLUMNS) + 0.5) * (end - start) / COLUMNS
    index = np.searchsorted(times, at, side="right") - 1  # the frame each column shows; -1: before the first
    shown = (index >= 0) & (at <= times[-1] + 1e-9)  # not before the first frame nor past the one shown
    chosen = states[np.maximum(index, 0)].T  # (modules, COLUMNS)
    lut = np.array([STOPPED, *(state_colour(k) for k in range(len(PALETTE)))])  # the palette repeats
    colour = np.where(chosen < 0, 0, 1 + chosen % len(PALETTE))
    cells = np.where(shown[None, :, None], lut[colour], NOTHING).astype(np.uint8)
    image = np.repeat(np.repeat(cells, CELL_HEIGHT, axis=0), CELL_WIDTH, axis=1)
    image[::CELL_HEIGHT, :, :] = np.minimum(image[::CELL_HEIGHT, :, :], 220)  # a faint line between modules
    if selected is not None and 0 <= selected < modules:
        top, bottom = selected * CELL_HEIGHT, (selected + 1) * CELL_HEIGHT - 1
        image[top : top + 2, :, :] = FRAME
        image[bottom - 1 : bottom + 1, :, :] = FRAME
    pixels_per_second = COLUMNS * CELL_WIDTH / (end - start)
    for second in np.arange(np.ceil(start), end, 1.0):
        x = int((second - start) * pixels_per_second)
        image[-4:, x : x + 1, :] = TICK
    if ended_at is not None and start <= ended_at <= end:
        x = min(int((ended_at - start) * pixels_per_second), image.shape[1] - 3)
        image[:, x : x + 3, :] = ENDED  # 3 px: the page shows the picture scaled to its panel
    return image


def legend(state_names: list[str]) -> str:
    """HTML: each state's colour and name, and the grey of a gait that no longer runs."""

    def swatch(rgb: np.ndarray) -> str:
        return (f'<span style="display:inline-block;width:10px;height:10px;background:rgb({rgb[0]},{rgb[1]},'
                f'{rgb[2]});margin:0 3px 0 8px"></span>')  # fmt: skip

    items = [swatch(state_colour(k)) + name for k, name in enumerate(state_names)]
    items.append(swatch(STOPPED) + "not running")
    return f'<div style="font-size:0.75em;line-height:1.6">{"".join(items)}</div>'
