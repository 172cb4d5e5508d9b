"""What the ``gaits`` command prints, read by a person or a pipe (issue 30's review, defect 15): a reader that goes
away ends it quietly, a free range too wide for a number is a usage error without numpy's warnings, and no "-0"
heading or "n/a … cost of transport" word salad."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gaits.cli import main
from gaits.metrics import unsigned_zero
from gaits.model import LIBRARY

pytestmark = pytest.mark.timeout(120)
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("command", [["expand", "--samples", "1024"], ["validate"]])
def test_a_reader_that_goes_away_ends_the_command_quietly(command: list[str]) -> None:
    files = [str(LIBRARY / "caterpillar.toml")] * (2000 if command == ["validate"] else 1)
    process = subprocess.Popen([sys.executable, "-m", "gaits.cli", *command, *files], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    assert process.stdout is not None and process.stderr is not None
    process.stdout.readline()  # `| head -1`
    process.stdout.close()
    err = process.stderr.read().decode()
    process.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err


def test_a_free_range_too_wide_for_a_number_is_a_usage_error(capsys, monkeypatch, tmp_path) -> None:
    monkeypatch.chdir(tmp_path)  # were it taken, the search would write its default file here
    with pytest.raises(SystemExit) as exit_:
        main(["tune", str(LIBRARY / "caterpillar.toml"), "--free", "amplitude=-1e308:1e308"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "HIGH - LOW finite" in err and "RuntimeWarning" not in err


def test_a_heading_is_never_minus_zero_and_the_cost_line_reads(capsys) -> None:
    assert unsigned_zero(-0.3, 0) == "0" and unsigned_zero(-0.04, 1) == "0.0" and unsigned_zero(-0.6, 0) == "-1"
    assert main(["simulate", str(LIBRARY / "caterpillar.toml"), "--seconds", "0.1", "--warmup", "0"]) == 0
    out = capsys.readouterr().out
    assert "\ncost of transport n/a (did not move); " in out and "-0.0 " not in out, out
