"""``gaits tune`` and ``gaits simulate`` as a user runs them (issue 30's review, defects 3, 4, 9, 10, 12 and 16):
nothing is written over the robot file, an unusable --out is refused before the search, a second Ctrl-C never hangs
the command, --max-torque goes as far as a stall torque does, a robot that cannot move is warned about, the
progress is a bar on a terminal, and the tuned file says which robot file described its modules."""

from __future__ import annotations

import io
import signal
from pathlib import Path

import pytest

from gaits.cli import main
from gaits.model import LIBRARY, load
from gaits.tune import Result, Setup

from .searches import interrupt, long_search, workers_of

pytestmark = [pytest.mark.xdist_group("test_tune"), pytest.mark.timeout(300)]
CATERPILLAR = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")
QUICK = ["--budget", "2", "--seconds", "0.3", "--warmup", "0.1", "--workers", "1"]


def with_robot_file(folder: Path, robot: str = "[robot.module]\nmass = 0.3\n") -> Path:
    (folder / "robot.toml").write_text(robot, encoding="utf-8")
    path = folder / "gait.toml"
    path.write_text(CATERPILLAR.replace("module_size = 0.05\n", 'module_size = 0.05\nfile = "robot.toml"\n', 1),
                    encoding="utf-8")  # fmt: skip
    return path


def test_neither_tune_nor_simulate_writes_over_the_robot_file(tmp_path, capsys) -> None:
    path = with_robot_file(tmp_path)
    (tmp_path / "link.toml").symlink_to(tmp_path / "robot.toml")
    before = (tmp_path / "robot.toml").read_bytes()
    for out in ("robot.toml", "link.toml", "./robot.toml"):
        assert main(["tune", str(path), "--free", "amplitude=20:80", *QUICK, "--out", str(tmp_path / out)]) == 2
        err = capsys.readouterr().err
        assert "is the gait's robot file (robot.toml)" in err and "tuning" not in err, err
        assert main(["simulate", str(path), "--seconds", "0.1", "--mjcf", str(tmp_path / out)]) == 2
        assert "is the gait's robot file (robot.toml)" in capsys.readouterr().err
    assert (tmp_path / "robot.toml").read_bytes() == before
    assert load(path).robot.module.mass == 0.3


@pytest.mark.parametrize(("out", "says"), [("/dev/full", "is not a regular file"),
                                           ("/proc/self/tuned.toml", "cannot be written")])  # fmt: skip
def test_an_unusable_out_is_refused_before_the_search(out: str, says: str, capsys) -> None:
    assert main(["tune", str(LIBRARY / "caterpillar.toml"), "--free", "amplitude=20:80", *QUICK, "--out", out]) == 2
    err = capsys.readouterr().err
    assert f"--out {out} {says}" in err and "tuning" not in err, err


def test_an_empty_out_is_no_file_name(capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["tune", str(LIBRARY / "caterpillar.toml"), "--free", "amplitude=20:80", "--out", ""])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "an empty file name" in err and "is a directory" not in err, err


def test_a_file_that_cannot_be_written_after_the_search_is_printed_not_lost(tmp_path, capsys, monkeypatch) -> None:
    out = tmp_path / "tuned.toml"

    def full(*args: object, **kwargs: object) -> int:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("gaits.tune_command.write_whole", full)
    assert main(["tune", str(LIBRARY / "caterpillar.toml"), "--free", "amplitude=20:80", *QUICK, "--out",
                 str(out)]) == 1  # fmt: skip
    captured = capsys.readouterr()
    assert "cannot be written now (No space left on device)" in captured.err and "amplitude=20:80 = " in captured.err
    assert captured.out.startswith("# Tuned by `gaits tune` from caterpillar.toml")
    assert "[automata.wave]" in captured.out


def test_a_write_that_fails_halfway_leaves_the_file_it_would_replace_whole(tmp_path) -> None:
    """A disk that fills during the write (here a file-size limit of 512 bytes, the tuned gait ~2 KB) left --out
    cut short, its old bytes gone and the new ones half there; now the old file stays as it was, nothing is left
    beside it, and the tuned gait follows on stdout (the review of the exit deadline, which could also cut a write)."""
    import resource
    import subprocess
    import sys

    from .searches import ROOT

    out = tmp_path / "tuned.toml"
    out.write_text("# an earlier search's gait\n", encoding="utf-8")

    def limited() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # past the limit a write fails (EFBIG) instead of a signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (512, 512))

    command = [sys.executable, "-m", "gaits.cli", "tune", str(LIBRARY / "caterpillar.toml"), "--free",
               "amplitude=20:80", *QUICK, "--out", str(out)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=120, preexec_fn=limited)
    assert done.returncode == 1, done.stderr
    assert "cannot be written now (File too large)" in done.stderr, done.stderr
    assert done.stdout.startswith("# Tuned by `gaits tune` from caterpillar.toml") and "[automata.wave]" in done.stdout
    assert out.read_text(encoding="utf-8") == "# an earlier search's gait\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tuned.toml"]


def test_the_torque_limit_goes_as_high_as_a_stall_torque(tmp_path, capsys) -> None:
    out = tmp_path / "tuned.toml"
    args = ["tune", str(LIBRARY / "caterpillar.toml"), "--free", "amplitude=20:80", *QUICK, "--out", str(out)]
    assert main([*args, "--max-torque", "500"]) == 0
    assert "constraints: peak torque <= 500 N·m" in out.read_text(encoding="utf-8")
    with pytest.raises(SystemExit):
        main([*args, "--max-torque", "10001"])
    assert "the torque limit must be > 0 and <= 10000, not 10001" in capsys.readouterr().err


def test_the_tuned_file_names_the_robot_file_and_a_robot_that_cannot_move_is_warned_of(tmp_path, capsys) -> None:
    path = with_robot_file(tmp_path, "[robot.module]\nmass = 20\nstall_torque = 1000\n")  # kp 10 moves no 20 kg
    out = tmp_path / "tuned.toml"
    code = main(["tune", str(path), "--free", "amplitude=20:80", *QUICK, "--max-torque", "1000", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "warning: the start moved less than a tenth of a body length" in err and "kp must grow" in err, err
    text = out.read_text(encoding="utf-8")
    assert "from gait.toml (its modules described by the robot file robot.toml)" in text.splitlines()[0]
    assert "; forward: none (the start moved less than a tenth of a body length" in text


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_progress_is_a_bar_on_a_terminal_and_lines_of_the_budget_elsewhere() -> None:
    from gaits.tune_command import Bar

    line = "generation 2: 12 of 60 simulations, best speed 0.25 m/s (this generation 0.2, 0 refused), sigma 0.2"
    result = Result(None, [], 0.25, 0.0, "", evaluations=12, generations=2)
    terminal = Terminal()
    bar = Bar(60, Setup(), terminal)
    bar(result, line)
    bar.close()
    shown = terminal.getvalue()
    assert "\r" in shown and "%|##" in shown and "| 12/60 simulations [" in shown, shown
    assert "], best speed 0.25 m/s" in shown, shown
    assert "generation 2" not in shown
    piped = io.StringIO()
    Bar(60, Setup(), piped)(result, line)
    assert piped.getvalue() == line + "\n"


def test_a_second_ctrl_c_does_not_hang_the_command(tmp_path) -> None:
    """The first Ctrl-C stops the search and writes the best so far; a second one a moment later (a user's double
    press) used to interrupt the exit handler and hang the command on its half shut pool until kill -9."""
    import psutil

    out = tmp_path / "tuned.toml"
    process = long_search(out)
    with workers_of(process) as workers:  # Ctrl-C again and again over the next second, whatever it is doing then
        workers += interrupt(process, "generation 2:", [signal.SIGINT] * 20)
        _, rest = process.communicate(timeout=60)
        assert process.returncode == 130, rest
        assert "Traceback" not in rest and "interrupted" in out.read_text(encoding="utf-8"), rest
        _, alive = psutil.wait_procs(workers, timeout=30)
        assert workers and not alive, f"workers left running: {alive}"


HUNG_EXIT = """
import atexit, sys, time
import gaits.tune_command
gaits.tune_command.EXIT_DEADLINE = 3.0
atexit.register(time.sleep, 3600)  # an exit handler that never returns, as a pool's thread stuck in its join would be
from gaits.cli import main
sys.exit(main())  # the command's own process: main() reads sys.argv, as `gaits` and `python -m gaits.cli` do
"""


def test_an_interrupted_command_ends_by_its_deadline_whatever_hangs_its_exit(tmp_path) -> None:
    """A CI run saw `gaits tune` not end within 60 s of a double Ctrl-C (once in ~40 runs, not reproduced since;
    its cause is read, not proved: an exit handler joining a pool's thread that never ends). Whatever hangs the
    exit of an interrupted search, the command writes its best gait and ends with 130 by ``EXIT_DEADLINE``; here an
    exit handler sleeps an hour."""
    import time

    import psutil

    out = tmp_path / "tuned.toml"
    process = long_search(out, entry=("-c", HUNG_EXIT))
    with workers_of(process) as workers:
        workers += interrupt(process, "generation 1:", [signal.SIGINT])
        began = time.monotonic()
        _, rest = process.communicate(timeout=60)
        took = time.monotonic() - began
        assert process.returncode == 130, rest
        assert "interrupted" in out.read_text(encoding="utf-8"), rest
        assert "did not exit within 3 s of the interruption: ending it now" in rest, rest
        assert 2.5 < took < 30, took
        _, alive = psutil.wait_procs(workers, timeout=30)
        assert workers and not alive, f"workers left running: {alive}"


IN_PROCESS = """
import os, signal, sys, threading, time
import gaits.tune_command as tc
tc.EXIT_DEADLINE = 1.0
said = tc.Bar.__call__
def interrupted_at_the_first_generation(self, result, line):
    said(self, result, line)
    os.kill(os.getpid(), signal.SIGINT)
tc.Bar.__call__ = interrupted_at_the_first_generation
from gaits.cli import main
code = main(sys.argv[1:])
time.sleep(3)  # three times the deadline
print(code, signal.getsignal(signal.SIGINT) is signal.default_int_handler, [t.name for t in threading.enumerate()])
"""


def test_a_caller_of_main_in_its_own_process_goes_on_after_an_interrupted_tune(tmp_path) -> None:
    """The exit deadline is the command's own process's: a test or a notebook calling ``main(["tune", ...])`` is
    neither ended 30 s after a Ctrl-C it passed on (the review of ``EXIT_DEADLINE``: it was) nor left with Ctrl-C
    ignored."""
    import subprocess
    import sys

    from .searches import ROOT

    out = tmp_path / "tuned.toml"
    command = [sys.executable, "-c", IN_PROCESS, "tune", str(LIBRARY / "caterpillar.toml"), "--free",
               "amplitude=20:85", *QUICK, "--budget", "200", "--out", str(out)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1].split(" ", 2)[:2] == ["130", "True"], done.stdout + done.stderr
    assert "gaits-tune-exit-deadline" not in done.stdout and "did not exit" not in done.stderr, done.stdout
    assert "interrupted" in out.read_text(encoding="utf-8")


def test_the_workers_end_when_the_command_is_killed(tmp_path) -> None:
    """kill -9 leaves the command no chance to end its workers: each notices its parent is gone and ends itself
    (they stayed, orphaned, for minutes)."""
    import psutil

    process = long_search(tmp_path / "tuned.toml")
    with workers_of(process) as workers:
        workers += interrupt(process, "generation 1:", [signal.SIGKILL])
        process.wait(timeout=10)
        _, alive = psutil.wait_procs(workers, timeout=20)
        assert workers and not alive, f"workers left running: {alive}"


def test_a_start_whose_simulation_diverges_is_one_line_not_a_traceback(tmp_path, capsys) -> None:
    """A second review: a module too stiff for the timestep (valid, each field in range) made `gaits simulate` say
    so in a line, and `gaits tune` print a FloatingPointError's traceback (the start's run finding its direction)."""
    stiff = tmp_path / "stiff.toml"
    module = "[robot.module]\nmass = 0.001\nkp = 100000\nstall_torque = 10000\ndamping = 0\n"
    stiff.write_text(CATERPILLAR.replace("module_size = 0.05\n", "module_size = 0.05\n" + module, 1), encoding="utf-8")
    out = tmp_path / "out.toml"
    assert main(["tune", str(stiff), "--free", "amplitude=20:85", *QUICK, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert f"gaits tune: error: {stiff}: the starting gait: the simulation diverged" in err, err
    assert "Traceback" not in err and not out.exists()


def test_a_best_worse_than_a_start_outside_the_bounds_is_written_with_a_warning(tmp_path, capsys) -> None:
    """A second review: bounds that exclude the start (a negative wavelength for a loop rolling forward) wrote a
    gait that rolls backwards, worse than the start, with nothing said."""
    out = tmp_path / "loop.toml"
    args = ["--budget", "3", "--seconds", "1", "--warmup", "0.5", "--workers", "1", "--out", str(out)]
    assert main(["tune", str(LIBRARY / "rolling_loop.toml"), "--free", "wavelength=-8:-3", *args]) == 0
    err = capsys.readouterr().err
    assert "warning: the best inside the bounds (-0." in err and "is worse than the start (0." in err, err
    assert out.exists()
