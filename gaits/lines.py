"""Where each field of a TOML document starts: one pass over the text, so that every problem a gait file has can be
given its 1-based line without rescanning the file per problem (a file with 80,000 bad states once took minutes).

The index maps field paths as the loader and the schema spell them (``robot.modules``, ``modules[3].phase``,
``automata.wave.states[2].angle``) to the line where the field, table or array item begins. It understands what
TOML allows for a gait file: ``[table]`` and ``[[array-of-tables]]`` headers, dotted and quoted keys, arrays and
inline tables spanning lines, every string form and comments. A path that is not in the index falls back to its
nearest ancestor that is (so a problem always has a line), and finally to line 1.
"""

from __future__ import annotations

import json
import re
import tomllib

_TOKEN = re.compile(
    r'"""(?:[^"\\]|\\.|"(?!""))*"""'  # multi-line basic string
    r"|'''(?:[^']|'(?!''))*'''"  # multi-line literal string
    r'|"(?:[^"\\\n]|\\.)*"'  # basic string
    r"|'[^'\n]*'"  # literal string
    r"|#[^\n]*"  # comment
    r"|\n"
    r"|[\[\]{},=.]"
    r"|[^\s\[\]{},=.#\"']+",  # bare key, number, date, true/false (a dotted float is split at '.', harmless)
    re.DOTALL,
)


def _key(token: str) -> str:
    if token[:1] == '"' and "\\" in token:  # a basic string's escapes, as the loader reads them ("a\u0000b")
        try:
            return tomllib.loads(f"k = {token}")["k"]
        except tomllib.TOMLDecodeError:
            return token[1:-1]
    if token[:1] in "\"'":
        return token[1:-1]
    return token


def format_path(parts: list[str | int]) -> str:
    """``["modules", 3, "phase"]`` → ``modules[3].phase``. A key with a character that does not print (a NUL, a
    newline) is shown quoted with TOML's escapes, as a file writes it: a message never carries it raw."""
    out = ""
    for part in parts:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            shown = part if part.isprintable() else json.dumps(part)
            out += f".{shown}" if out else shown
    return out


class LineIndex:
    """Field path → 1-based line of a TOML text, built once."""

    def __init__(self, text: str) -> None:
        self._lines: dict[str, int] = {}
        self._build(text)

    def line(self, path: str) -> int:
        """The line where ``path`` (or its nearest ancestor in the file) begins; 1 if nothing of it is."""
        while path:
            if path in self._lines:
                return self._lines[path]
            cut = max(path.rfind("."), path.rfind("["))
            if cut <= 0:
                break
            path = path[:cut]
        return self._lines.get(path, 1)

    def _mark(self, parts: list[str | int], line: int) -> None:
        self._lines.setdefault(format_path(parts), line)

    def _build(self, text: str) -> None:
        line = 1
        table: list[str | int] = []
        arrays_of_tables: dict[tuple[str | int, ...], int] = {}
        # The value stack: one entry per open array or inline table, with the path of the container and, for an
        # array, the index of the next item; for an inline table, the key being read.
        stack: list[tuple[str, list[str | int], list[int]]] = []
        key: list[str] = []
        in_scalar = False  # inside a scalar value (a float's '.', a date's ':'): nothing in it is a key or an item
        at_line_start = True
        tokens = _TOKEN.finditer(text)
        for match in tokens:
            token = match.group()
            if token == "\n":
                line += 1
                at_line_start = not stack
                if not stack:
                    in_scalar, key = False, []
                continue
            if token[0] == "#":
                continue
            if token[:3] in ('"""', "'''"):
                line += token.count("\n")
            if not stack and at_line_start and token == "[":
                line = self._header(tokens, table, arrays_of_tables, line)
                continue
            at_line_start = False
            if stack and stack[-1][0] == "array":
                _, base, state = stack[-1]  # state: [next index, an item is open]
                if token == "]":
                    stack.pop()
                    in_scalar = bool(stack)  # the array was a value: what follows until ',' or '}' is not a key
                elif token == ",":
                    state[1] = 0
                elif not state[1]:
                    item = [*base, state[0]]
                    state[0], state[1] = state[0] + 1, 1
                    self._mark(item, line)
                    if token == "[":
                        stack.append(("array", item, [0, 0]))
                    elif token == "{":
                        stack.append(("table", item, [0, 0]))
                        key, in_scalar = [], False
                continue
            if token == "}" and stack:
                stack.pop()
                key, in_scalar = [], bool(stack) and stack[-1][0] == "table"
                continue
            if token == "," and stack:
                key, in_scalar = [], False
                continue
            if in_scalar or token == ".":
                continue
            if token == "=":
                path = [*(stack[-1][1] if stack else table), *key]
                self._mark(path, line)
                value = next(tokens, None)  # TOML puts the value on the same line as its '='
                if value is None:
                    return
                v = value.group()
                if v[:3] in ('"""', "'''"):
                    line += v.count("\n")
                if v == "[":
                    stack.append(("array", path, [0, 0]))
                elif v == "{":
                    stack.append(("table", path, [0, 0]))
                else:
                    in_scalar = True
                key = []
                continue
            key.append(_key(token))

    def _header(self, tokens, table: list[str | int], arrays: dict[tuple[str | int, ...], int], line: int) -> int:
        """Read a ``[a.b]`` or ``[[a.b]]`` header (the first '[' already taken) and make it the current table."""
        parts: list[str] = []
        double = False
        for match in tokens:
            token = match.group()
            if token == "[" and not parts:
                double = True
            elif token == "]":
                break
            elif token == "\n":
                return line + 1
            elif token != ".":
                parts.append(_key(token))
        if double:
            next(tokens, None)  # the second ']'
        path: list[str | int] = []
        for part in parts:  # a header below an array of tables names its latest item: [[a]] then [a.b] is a[-1].b
            path.append(part)
            if tuple(path) in arrays and len(path) < len(parts):
                path.append(arrays[tuple(path)] - 1)
        if double:
            index = arrays.get(tuple(path), 0)
            arrays[tuple(path)] = index + 1
            self._mark(path, line)
            path.append(index)
        table[:] = path
        self._mark(table, line)
        return line
