"""Bytes to a checked document: decoding, TOML, the JSON Schema (gaits/schema.json), and the line of each problem.

The schema is the one description of the gait format's structure — which fields exist, their types, ranges and
sizes. The loader validates every document with it and keeps in code only the checks a schema cannot state (angles
within the file's own limits, every module assigned once, one shared period, finite numbers), so the schema and the
loader cannot disagree about structure. Every cost is bounded before it is paid: the file's size before it is
parsed, nesting depth by the parser, array sizes by the schema before anything is sized by them, and the number of
problems collected.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator, validators
from jsonschema.exceptions import ValidationError

from .errors import MAX_LISTED, GaitError, Problem
from .lines import LineIndex, format_path

MAX_FILE_BYTES = 2 * 1024 * 1024
"""A gait file is at most 2 MiB (254 modules with an automaton of 64 states each is about 1 MiB)."""
MAX_COUNTED = 1000
"""Problems counted before validation stops (only the first MAX_LISTED are listed)."""

SCHEMA: dict[str, Any] = json.loads((Path(__file__).resolve().parent / "schema.json").read_text(encoding="utf-8"))
Validator = validators.extend(Draft202012Validator, type_checker=Draft202012Validator.TYPE_CHECKER.redefine(
    "integer", lambda _, value: isinstance(value, int) and not isinstance(value, bool)))  # fmt: skip
"""JSON Schema 2020-12 as TOML needs it: an integer is TOML's integer. JSON counts ``1.0`` as one, so a module ID of
``1.0`` passed and was written back as ``1.0``."""
_VALIDATOR = Validator(SCHEMA)


def read(path: str | Path) -> bytes:
    """The file's bytes, no more than one byte past the largest gait file (``decode`` refuses it then): a huge
    file is never read whole."""
    with open(path, "rb") as file:
        return file.read(MAX_FILE_BYTES + 1)


def _too_large(source: str, kind: str) -> GaitError:
    return GaitError(
        source, [Problem("(file)", f"larger than {MAX_FILE_BYTES // 1024 // 1024} MiB: not a {kind} file", 1)]
    )


def decode(data: bytes | str, source: str, kind: str = "gait") -> str:
    """UTF-8 text (a leading byte-order mark is allowed); a bad byte is reported with its line. ``kind``: what the
    file should be ("gait", "robot"), as a file too large is said to be none."""
    if len(data) > MAX_FILE_BYTES:  # checked before decoding: bytes never decode to more characters
        raise _too_large(source, kind)
    if isinstance(data, str):
        return data.removeprefix("\ufeff")
    try:
        return data.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        message = f"not UTF-8 text: byte 0x{data[exc.start]:02x} at offset {exc.start} cannot be decoded"
        raise GaitError(source, [Problem("(file)", message, line)]) from None


def parse(text: str, source: str) -> dict[str, Any]:
    """The TOML document as a dict; GaitError (with the parser's line) when it is not TOML."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        found = re.search(r"line (\d+)", str(exc))
        raise GaitError(source, [Problem("(file)", f"not valid TOML: {exc}", int(found[1]) if found else 1)]) from None
    except RecursionError:
        raise GaitError(source, [Problem("(file)", "arrays or tables nested too deeply", 1)]) from None
    except ValueError:  # an integer with more digits than Python converts (4,300)
        raise GaitError(
            source, [Problem("(file)", "not a usable TOML document: a number too long to read", 1)]
        ) from None


def brief(value: Any) -> str:
    """A value as a problem quotes it: short whatever its size."""
    if isinstance(value, dict):
        return f"a table of {len(value)} field(s)"
    if isinstance(value, list):
        return f"an array of {len(value)} item(s)"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "…"


_TYPES = {"string": "a string", "integer": "an integer", "number": "a number", "object": "a table",
          "array": "an array", "boolean": "true or false"}  # fmt: skip


def _range(schema: dict[str, Any]) -> str:
    low = (
        f"[{schema['minimum']:g}"
        if "minimum" in schema
        else (f"({schema['exclusiveMinimum']:g}" if "exclusiveMinimum" in schema else "(-∞")
    )
    high = (
        f"{schema['maximum']:g}]"
        if "maximum" in schema
        else (f"{schema['exclusiveMaximum']:g})" if "exclusiveMaximum" in schema else "∞)")
    )
    unit = str(schema.get("description", "")).split(";")[0]
    # a short description is the number's unit ("kg", "N·m"): a mass of -1 is then refused in words a person reads
    return f"{low}, {high}" + (f" {unit}" if unit and len(unit) <= 24 and ":" not in unit else "")  # fmt: skip


def _problems(error: ValidationError) -> Iterator[tuple[list[str | int], str]]:
    """One schema error as (path, message) pairs, worded for a person editing the file."""
    path: list[str | int] = list(error.absolute_path)
    # jsonschema types these as "maybe unset" for errors built by hand; a validator's own errors always set them.
    kind: Any = error.validator
    value: Any = error.validator_value
    schema: Any = error.schema
    instance: Any = error.instance
    if "propertyNames" in error.schema_path:  # a table key (an automaton's name) that breaks the rules for names
        if kind == "pattern":  # the name's own schema says in words what a name is
            yield [*path, instance], f"{schema.get('description', 'a name')}, not {brief(instance)}"
        else:
            longest = schema.get("maxLength", 64)
            yield [*path, instance], f"names must be 1 to {longest} characters long, not {len(instance)}"
    elif kind in ("additionalProperties", "unevaluatedProperties") and value is False:
        known = set(schema.get("properties", {})) | set(_referenced(schema).get("properties", {}))
        for key in sorted(set(instance) - known):
            yield [*path, key], "unknown field"
    elif kind == "required":
        for key in value:
            if key not in instance:
                yield [*path, key], "missing"
    elif kind == "type":
        yield path, f"must be {_TYPES.get(value, value)}, not {brief(instance)}"
    elif kind == "enum":
        yield path, f"must be one of {', '.join(json.dumps(v) for v in value)}, not {brief(instance)}"
    elif kind in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        yield path, f"must be in {_range(schema)}, not {brief(instance)}"
    elif kind in ("minItems", "maxItems"):
        low, high = schema.get("minItems", 0), schema.get("maxItems", "∞")
        yield path, f"must have {low if low == high else f'{low} to {high}'} items, not {len(instance)}"
    elif kind in ("minProperties", "maxProperties"):
        low, high = schema.get("minProperties", 0), schema.get("maxProperties", "∞")
        yield path, f"must have {low} to {high} entries, not {len(instance)}"
    elif kind in ("minLength", "maxLength"):
        low, high = schema.get("minLength", 0), schema.get("maxLength", "∞")
        yield path, f"must be {low} to {high} characters long, not {len(instance)}"
    elif kind == "anyOf" and path and path[-2:-1] == ["states"]:
        yield path, "needs a duration or the event it waits for (until)"
    else:
        message = error.message
        yield path, message if len(message) <= 200 else message[:197] + "…"


def _referenced(schema: dict[str, Any]) -> dict[str, Any]:
    """The definition a schema's ``$ref`` names (``#/$defs/NAME``), whose fields it extends; {} without one."""
    ref = schema.get("$ref", "")
    return SCHEMA["$defs"][ref.removeprefix("#/$defs/")] if ref.startswith("#/$defs/") else {}


def structure_problems(
    data: Any, line: Callable[[str], int | None], validator: Any = _VALIDATOR
) -> tuple[list[Problem], int]:
    """What the schema (``validator``'s: a gait file's unless told) refuses in ``data``: the first MAX_COUNTED
    problems, and how many more were not counted."""
    problems: list[Problem] = []
    said: set[tuple[str, str]] = set()
    errors = validator.iter_errors(data)  # lazy: stopping early bounds the cost on a huge bad document
    for error in errors:
        for parts, message in _problems(error):
            path = format_path(parts) or "(document)"
            shown = path if len(path) <= 120 else path[:119] + "…"  # a key can be as long as the file
            if (shown, message) in said:  # the schema's alternatives (program or gait) each miss the same field
                continue
            said.add((shown, message))
            problems.append(Problem(shown, message, line(path)))
        if len(problems) >= MAX_COUNTED:
            return problems, 1 if next(errors, None) is not None else 0
    return problems, 0


def raise_if(problems: list[Problem], source: str, *, uncounted: int = 0) -> None:
    """GaitError listing the first problems in file order, if there are any."""
    if problems:
        ordered = sorted(problems, key=lambda p: p.line or 0)
        listed = ordered[:MAX_LISTED]
        raise GaitError(
            source, listed, more=len(ordered) - len(listed) + uncounted, more_is_lower_bound=bool(uncounted)
        )


class Checker:
    """The problems of one document, each with its line: the line index is built once, and only when a problem needs
    it (a document built in memory, without ``text``, has no lines)."""

    def __init__(self, source: str, text: str | None, *, file: str | None = None) -> None:
        self.source = source
        self.text = text
        self.file = file
        """The file's name in each problem when it is not the gait file (a robot file)."""
        self.problems: list[Problem] = []
        self._index: LineIndex | None = None

    def line(self, path: str) -> int | None:
        if self.text is None:
            return None
        if self._index is None:
            self._index = LineIndex(self.text)
        return self._index.line(path)

    def bad(self, path: str, message: str) -> None:
        self.problems.append(Problem(path, message, self.line(path)))

    def raise_if(self, *, uncounted: int = 0) -> None:
        raise_if([replace(p, file=self.file) for p in self.problems], self.source, uncounted=uncounted)

    def check_structure(self, data: Any, validator: Any = _VALIDATOR) -> None:
        """GaitError unless ``data`` has the schema's structure and only finite numbers: what every other check
        relies on."""
        self.problems, uncounted = structure_problems(data, self.line, validator)
        said = {problem.path for problem in self.problems}
        for parts in non_finite(data, []):  # with the schema's, so that every problem is said at once (a nan
            path = format_path(parts)  # passes the schema's ranges: it came out only once the others were fixed)
            if path not in said:
                self.bad(path, "must be a finite number, not nan or inf")
        self.raise_if(uncounted=uncounted)


def non_finite(value: Any, path: list[str | int]) -> Iterator[list[str | int]]:
    """Paths of nan and inf in a document (TOML has them, JSON, and so the schema, does not)."""
    if isinstance(value, float) and not math.isfinite(value):
        yield path
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from non_finite(item, [*path, key])
    elif isinstance(value, list):
        for k, item in enumerate(value):
            yield from non_finite(item, [*path, k])
