"""What a bad gait file is told: every problem with its field path and line, in one exception."""

from __future__ import annotations

from dataclasses import dataclass, replace

from asm_py.errors import AsmError

MAX_LISTED = 50
"""Problems listed in a GaitError's message; the rest are counted ("… and N more")."""


@dataclass(frozen=True)
class Problem:
    path: str
    """Where: a dotted field path such as ``modules[3].phase`` (array indexes 0-based, as in the file's arrays)."""
    message: str
    line: int | None = None
    """1-based line in the file (None only for a document built in memory, which has no lines)."""
    file: str | None = None
    """The file the problem is in when it is not the gait file itself: the robot file it names (gaits/robot.py)."""

    def __str__(self) -> str:
        where = [self.file] if self.file is not None else []
        where += [f"line {self.line}"] if self.line else []
        return f"{', '.join(where)}{': ' if where else ''}{self.path}: {self.message}"


class GaitError(AsmError, ValueError):
    """A gait file that cannot be used; ``problems`` lists the first reasons, ``more`` counts the rest."""

    def __init__(
        self, source: str, problems: list[Problem], *, more: int = 0, more_is_lower_bound: bool = False
    ) -> None:
        self.source = source
        self.problems = problems[:MAX_LISTED]
        self.more = more + max(0, len(problems) - MAX_LISTED)
        self._rest = f"and {'at least ' if more_is_lower_bound else ''}{self.more} more" if self.more else ""
        said = [str(replace(p, file=None) if p.file == source else p) for p in self.problems]  # named once
        super().__init__(f"{source}: " + "; ".join(said + ([self._rest] if self._rest else [])))

    def lines(self) -> list[str]:
        """One line per listed problem, and a last one counting those not listed."""
        return [str(p) for p in self.problems] + ([f"… {self._rest}"] if self._rest else [])
