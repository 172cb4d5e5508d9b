"""Saving a gait without losing its file: the comments, order and layout of the TOML it was opened from are kept,
and only what changed is rewritten (tomlkit, a round-tripping TOML library). A gait that has no file (made by the
generator) is written with its units in comments.

Whatever is written is checked: parsed back, it must be exactly the gait's data; if the merge cannot guarantee that
(an exotic layout), the plain annotated form is written instead, so a save is never wrong, at worst less pretty.
"""

from __future__ import annotations

import tomllib
from typing import Any

import tomli_w
import tomlkit
from tomlkit.items import AoT, Array, InlineTable, Table

UNITS = {
    ("robot", "module_size"): "metres",
    ("limits", "min"): "degrees",
    ("limits", "max"): "degrees",
    ("robot.module", "length"): "metres",
    ("robot.module", "width"): "metres",
    ("robot.module", "height"): "metres",
    ("robot.module", "mass"): "kg",
    ("robot.module", "stall_torque"): "N·m",
    ("robot.module", "no_load_speed"): "degrees per second",
    ("robot.module", "kp"): "N·m per radian",
    ("robot.module", "damping"): "N·m·s per radian",
    ("robot.module", "deadband"): "degrees",
    ("robot.module", "range"): "± degrees",
    ("robot.module", "inertia"): "kg·m² about the centre: along, across, up",
    ("ground", "friction"): "Coulomb μ between modules and the ground",
    ("ground", "anisotropic"): "[μ along each module, μ across it]",
}
HEADER = ("# A gait for ASM Studio (gaits/README.md).\n"
          "# Angles in degrees, durations in seconds, phases in cycles [0, 1); direction -1 runs an automaton "
          "backwards.\n")  # fmt: skip


def save(data: dict[str, Any], original: str | None) -> str:
    """``data`` (a gait document's dict) as TOML, keeping ``original``'s comments and layout where it can."""
    if original is not None:
        try:
            document = tomlkit.parse(original)
            _merge(document, data)
            text = tomlkit.dumps(document)
            if tomllib.loads(text) == data:
                return text
        except Exception:  # any failure of the merge falls back to the plain form below
            pass
    return annotated(data)


def annotated(data: dict[str, Any]) -> str:
    """The plain TOML of ``data`` with a header and each unit in a comment on its line."""
    lines, table = [], ""
    for line in tomli_w.dumps(data).splitlines():
        stripped = line.strip()
        if stripped.startswith("[") and not stripped.startswith("[["):
            table = stripped.strip("[]").strip()
        key = stripped.split("=", 1)[0].strip() if "=" in stripped else ""
        described = "robot.module" if table.startswith("robot.types.") else table  # a named type: the same units
        unit = UNITS.get((described, key))
        lines.append(f"{line}  # {unit}" if unit and not stripped.endswith(("[", "{")) else line)
    return HEADER + "\n".join(lines) + "\n"


def _merge(container: Any, new: dict[str, Any]) -> None:
    """Make the tomlkit ``container`` hold ``new``, touching only the keys whose values differ."""
    for key in [k for k in container if k not in new]:
        del container[key]
    for key, value in new.items():
        old = container.get(key) if key in container else None
        if isinstance(value, dict) and isinstance(old, Table | InlineTable):
            _merge(old, value)
        elif (
            isinstance(value, list)
            and isinstance(old, Array | AoT)
            and len(old) == len(value)
            and all(isinstance(v, dict) for v in value)
        ):
            for old_item, new_item in zip(old, value, strict=True):
                if isinstance(old_item, Table | InlineTable):
                    _merge(old_item, new_item)
                else:
                    raise ValueError("an array changed its kind")
        elif old is None or _plain(old) != value or type(_plain(old)) is not type(value):
            container[key] = value


def _plain(item: Any) -> Any:
    return item.unwrap() if hasattr(item, "unwrap") else item
