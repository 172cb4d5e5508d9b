"""A corpus of malformed gait files, made by mutating the library's files, run through the loader and `gaits validate`.

Each file must give a GaitError (never another exception, a hang or unbounded output) whose every problem has a
field path and a 1-based line, and the loader must agree with gaits/schema.json: a document the schema refuses is
refused, and a document the loader accepts is one the schema accepts.
"""

from __future__ import annotations

import copy
import math
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import tomli_w
from hypothesis import given, settings
from hypothesis import strategies as st

from gaits.errors import MAX_LISTED
from gaits.model import LIBRARY, GaitError, loads
from gaits.validate import MAX_FILE_BYTES, SCHEMA

BASES = {path.stem: path.read_text(encoding="utf-8") for path in sorted(LIBRARY.glob("*.toml"))}
WRONG_VALUES: list[Any] = ["8", "1s", 1.5, True, [1], {"a": 1}, -1, 10**12, math.nan, "", [["wave"]]]
SCHEMA_ONLY = [  # documents the hand-written checks once accepted, and the schema refuses
    ("no robot table", lambda d: d.pop("robot")),
    ("description = 5", lambda d: d.__setitem__("description", 5)),
    ("robot.legs = 'four'", lambda d: d["robot"].__setitem__("legs", "four")),
    ("no automaton on a module", lambda d: d["modules"][0].pop("automaton")),
    ("no modules", lambda d: d.__setitem__("modules", [])),
    ("a state without an angle", lambda d: next(iter(d["automata"].values()))["states"][0].pop("angle")),
    (
        "2000 states",
        lambda d: next(iter(d["automata"].values())).__setitem__("states", [{"angle": 0.0, "duration": 0.01}] * 2000),
    ),
    (
        "an automaton name of 100 characters",
        lambda d: d["automata"].__setitem__("x" * 100, {"states": [{"angle": 0.0, "duration": 1.0}]}),
    ),
    ("unknown top-level field", lambda d: d.__setitem__("colour", "red")),
    ("unknown state field", lambda d: next(iter(d["automata"].values()))["states"][0].__setitem__("speed", 1)),
    ("name of 1000 characters", lambda d: d.__setitem__("name", "n" * 1000)),
    ("duration of a day", lambda d: next(iter(d["automata"].values()))["states"][0].__setitem__("duration", 86400.0)),
]


def fields(doc: dict[str, Any]) -> Iterator[list[str | int]]:
    """Every leaf field of a library document worth mutating (one state and one module stand for all)."""
    for key in ("name", "description"):
        if key in doc:
            yield [key]
    for table in ("robot", "limits", "ground"):
        for key in doc.get(table, {}):
            yield [table, key]
    for table in ("robot", "limits", "automata", "modules"):
        yield [table]
    auto = next(iter(doc["automata"]))
    yield ["automata", auto, "states"]
    for key in doc["automata"][auto]["states"][0]:
        yield ["automata", auto, "states", 0, key]
    for key in doc["modules"][0]:
        yield ["modules", 0, key]


def put(doc: Any, path: list[str | int], value: Any) -> None:
    for part in path[:-1]:
        doc = doc[part]
    doc[path[-1]] = value


def corpus() -> Iterator[tuple[str, bytes]]:
    for stem, text in BASES.items():
        doc = tomllib.loads(text)
        for path in fields(doc):
            for value in WRONG_VALUES if stem in ("caterpillar", "legged_walk") else WRONG_VALUES[:3]:
                mutated = copy.deepcopy(doc)
                put(mutated, path, value)
                yield f"{stem}: {'.'.join(map(str, path))} = {value!r}"[:80], tomli_w.dumps(mutated).encode()
        for name, mutate in SCHEMA_ONLY:
            mutated = copy.deepcopy(doc)
            mutate(mutated)
            yield f"{stem}: {name}", tomli_w.dumps(mutated).encode()
    text = BASES["caterpillar"]
    raw = text.encode()
    for offset in (0, len(raw) // 2, len(raw) - 1):
        yield f"non-UTF-8 byte at {offset}", raw[:offset] + b"\xff\xfe" + raw[offset:]
    yield "Latin-1 description", raw.replace("A 50°".encode(), "A 50°".encode("latin-1"))
    yield "NUL bytes", raw.replace(b"caterpillar", b"cater\x00pillar")
    for depth in (50, 2000):
        yield f"arrays nested {depth} deep", (text + "x = " + "[" * depth + "]" * depth + "\n").encode()
        yield (
            f"inline tables nested {depth} deep",
            (text + "x = " + "{a = " * depth + "1" + "}" * depth + "\n").encode(),
        )
        nested = text.replace('name = "caterpillar"', "name = " + "[" * depth + '"c"' + "]" * depth)
        yield f"name nested {depth} deep", nested.encode()
    yield "robot.modules = 10**12", text.replace("modules = 8", "modules = 1000000000000").encode()
    yield "robot.modules = 10**6", text.replace("modules = 8", "modules = 1000000").encode()
    yield "robot.modules of 5000 digits", text.replace("modules = 8", "modules = " + "9" * 5000).encode()
    bad_state = "{ angle = 999.0, duration = -1, interpolation = 'x' },\n"
    many = text.replace("states = [\n", "states = [\n" + bad_state * ((MAX_FILE_BYTES - len(raw)) // len(bad_state)))
    yield "as many bad states as fit in 2 MiB", many.encode()
    yield "10 MB of states", text.replace("states = [\n", "states = [\n" + bad_state * 200_000).encode()
    yield "empty file", b""
    yield "not TOML", b"\x89PNG\r\n\x1a\n" + bytes(range(256))
    yield "a TOML array at the top", b"modules = [1, 2]\n"


CASES = list(corpus())


def test_the_corpus_is_large_enough() -> None:
    assert len(CASES) >= 80, len(CASES)


@pytest.mark.parametrize(("name", "data"), CASES, ids=[name for name, _ in CASES])
def test_a_malformed_file_gets_a_gait_error_with_lines_and_agrees_with_the_schema(name: str, data: bytes) -> None:
    started = time.monotonic()
    try:
        gait = loads(data, source="corpus.toml")
        error = None
    except GaitError as exc:
        gait, error = None, exc
    assert time.monotonic() - started < 20  # generous: bench/gaits.py measures the 2 s target
    if error is not None:
        assert error.problems and len(error.problems) <= MAX_LISTED
        for problem in error.problems:
            assert problem.path and problem.message and isinstance(problem.line, int) and problem.line >= 1, problem
        assert len(str(error)) < 20_000
    try:
        document = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError, ValueError):
        assert error is not None
        return
    schema_accepts = jsonschema.Draft202012Validator(SCHEMA).is_valid(document)
    if not schema_accepts:
        assert error is not None, f"{name}: the schema refuses it, the loader accepted it"
    if gait is not None:
        assert schema_accepts, name


def test_library_files_pass_both() -> None:
    for stem, text in BASES.items():
        loads(text.encode(), source=stem)
        jsonschema.validate(tomllib.loads(text), SCHEMA)


def test_gaits_validate_answers_every_corpus_file_without_a_traceback(tmp_path: Path) -> None:
    paths = []
    for k, (_, data) in enumerate(CASES):
        path = tmp_path / f"case{k:03}.toml"
        path.write_bytes(data)
        paths.append(str(path))
    result = subprocess.run([sys.executable, "-m", "gaits.cli", "validate", *paths], capture_output=True,
                            text=True, timeout=300)  # fmt: skip
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    answered = [line for line in (result.stdout + result.stderr).splitlines() if line.startswith(str(tmp_path))]
    assert len(answered) == len(paths)
    assert len(result.stderr) < 100 * 1024 * len(paths) // 10  # at most 50 problems a file, each a line


def test_problems_are_listed_up_to_fifty_then_counted() -> None:
    text = BASES["caterpillar"].replace("states = [\n", "states = [\n" + "{ angle = 999.0, duration = 1.0 },\n" * 300)
    with pytest.raises(GaitError) as caught:
        loads(text)
    assert len(caught.value.problems) == MAX_LISTED
    assert caught.value.more > 200
    assert str(caught.value).endswith(f"and {caught.value.more} more")
    lines = [p.line for p in caught.value.problems]
    assert (
        lines == sorted(lines) and lines[0] == 28
    )  # in file order, from the first bad state (the line after "states = [")


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_any_mutation_of_a_library_file_gives_a_gait_or_a_gait_error(data: st.DataObject) -> None:
    """Random edits of a library file's bytes (insert, delete, replace runs of bytes): never another exception."""
    raw = bytearray(BASES[data.draw(st.sampled_from(sorted(BASES)))].encode())
    for _ in range(data.draw(st.integers(1, 5))):
        at = data.draw(st.integers(0, len(raw)))
        end = min(len(raw), at + data.draw(st.integers(0, 8)))
        raw[at:end] = data.draw(st.binary(max_size=8) | st.sampled_from([b"[", b"]", b"{", b"=", b'"', b"\n", b"nan"]))
    try:
        loads(bytes(raw))
    except GaitError as exc:
        assert all(isinstance(p.line, int) and p.line >= 1 for p in exc.problems)
