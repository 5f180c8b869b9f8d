"""Your own filter on the command line: new-filter, filter/evaluate --estimator FILE.py, serve
--filter --forward. Errors in your code: file:line and message (traceback on demand), status 1;
a file that cannot be used at all: one line, status 2."""

from __future__ import annotations

import csv
import io
import socket
import threading

import pytest

from app import cli
from user_filters import log_lines, write_filter


@pytest.fixture
def log(tmp_path):
    path = tmp_path / "log.txt"
    path.write_bytes(b"".join(log_lines(3.0)))
    return path


def test_new_filter_writes_the_template_and_never_overwrites(tmp_path, capsys):
    path = tmp_path / "mine.py"
    assert cli.main(["new-filter", str(path)]) == 0
    text = path.read_text()
    for name in ("def tu_qw(x, P, omega, T, Rw):", "def mu_g(x, P, yacc, Ra, g0):",
                 "def mu_m(x, P, ymag, m0, Rm):", "def mu_normalizeQ(x, P):", "class Filter:",
                 "def step(self, t, gyr, acc, mag):"):
        assert name in text
    assert "mine.py" in capsys.readouterr().out
    path.write_text("my work")
    assert cli.main(["new-filter", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already; not overwritten" in err
    assert path.read_text() == "my work"
    assert cli.main(["new-filter", str(tmp_path / "mine.txt")]) == 2
    assert "ends in .py" in capsys.readouterr().err


def test_filter_with_the_template_is_flat_and_lists_the_missing_steps(tmp_path, log, capsys):
    mine = tmp_path / "mine.py"
    cli.main(["new-filter", str(mine)])
    capsys.readouterr()
    assert cli.main(["filter", str(log), "--estimator", str(mine)]) == 0
    out, err = capsys.readouterr()
    rows = list(csv.reader(io.StringIO(out)))
    assert rows[0][:5] == ["t_ms", "qw", "qx", "qy", "qz"] and len(rows) == 301
    assert {tuple(r[1:5]) for r in rows[1:]} == {("1.000000000", "0.000000000", "0.000000000",
                                                  "0.000000000")}
    assert "mine.py: not written yet (skipped): tu_qw (mine.py:" in err


def test_what_your_filter_prints_goes_to_stderr_not_into_the_csv(tmp_path, log, capsys):
    path = write_filter(tmp_path, "chatty", """
        class Filter:
            def step(self, t, gyr, acc, mag):
                print("debug", t)
                return [1.0, 0.0, 0.0, 0.0]
    """)
    assert cli.main(["filter", str(log), "--estimator", str(path)]) == 0
    out, err = capsys.readouterr()
    assert "debug" not in out and "debug 1.0" in err


def test_a_failing_filter_names_its_line_and_exits_1(tmp_path, log, capsys):
    path = write_filter(tmp_path, "raises")
    out_csv = tmp_path / "est.csv"
    assert cli.main(["filter", str(log), "--estimator", str(path), "-o", str(out_csv)]) == 1
    err = capsys.readouterr().err
    assert "your filter stopped: raises.py:11 in update: ValueError" in err
    assert "--traceback" in err and "Traceback" not in err and not out_csv.exists()
    assert cli.main(["filter", str(log), "--estimator", str(path), "--traceback"]) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "return np.ones(2) @ acc" in err


def test_the_traceback_shows_only_your_frames(tmp_path, log, capsys):
    """Issue 51: a step whose arguments do not match the call showed Orientation Lab's own
    frame (the call site in app/engine/userfilter) as the traceback of the user's code."""
    path = write_filter(tmp_path, "few_arguments", """
        class Filter:
            def step(self, t):
                return [1.0, 0.0, 0.0, 0.0]
    """)
    assert cli.main(["filter", str(log), "--estimator", str(path), "--traceback"]) == 1
    err = capsys.readouterr().err
    assert "few_arguments.py: TypeError: Filter.step() takes 2 positional arguments" in err
    assert "app/engine" not in err and "app\\engine" not in err and 'File "' not in err
    assert "no line of it ran" in err
    nested = write_filter(tmp_path, "nested", """
        import numpy as np

        class Filter:
            def step(self, t, gyr, acc, mag):
                return helper(acc)

        def helper(acc):
            return np.linalg.inv(np.zeros((3, 3)))
    """)
    assert cli.main(["filter", str(log), "--estimator", str(nested), "--traceback"]) == 1
    err = capsys.readouterr().err
    frames = [line for line in err.splitlines() if line.strip().startswith('File "')]
    assert 'nested.py", line 6, in step' in frames[0] and "in helper" in frames[1]
    assert not any("/app/" in line or "/ekf/" in line for line in frames)


def test_evaluate_compares_your_filter_with_ours(tmp_path, log, capsys):
    good = write_filter(tmp_path, "flat")
    bad = write_filter(tmp_path, "nan")
    assert cli.main(["evaluate", str(log), "--estimator", f"course,{good},{bad}"]) == 1
    out, err = capsys.readouterr()
    table = {line.split()[0]: line.split()[1:] for line in out.splitlines()[2:]}
    assert set(table) == {"course", "flat.py", "nan.py"}
    assert float(table["flat.py"][1]) == 0.0          # ORI is flat: so is this filter
    assert table["nan.py"] == ["stopped:", "see", "above"]
    assert "nan.py: Filter.step returned garbage at t = 1.510 s: q is not finite" in err


@pytest.mark.parametrize("body, needle", [
    (None, "no such filter file"),
    ("class Filter:\n    def step(self, t, gyr, acc, mag)\n", "bad.py:2: SyntaxError"),
    ("class Filter:\n    pass\n", "bad.py: no class Filter with a method step"),
])
def test_a_file_that_cannot_be_used_is_one_line_and_exit_2(tmp_path, log, capsys, body, needle):
    path = tmp_path / "bad.py"
    if body is not None:
        path.write_text(body)
    assert cli.main(["evaluate", str(log), "--estimator", f"ekf,{path}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


@pytest.mark.parametrize("argv, needle", [
    (["--filter", "/no/such.py", "--exit-after", "0"], "no such filter file"),
    (["serve", "--forward", "host:99999"], "port out of range"),
    (["serve", "--filter", "notes.txt"],
     "your filter is a Python file (.py) or a folder of MATLAB .m files"),
])
def test_bad_filter_and_forward_options(capsys, argv, needle):
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 2 and needle in capsys.readouterr().err


def test_serve_runs_your_filter_and_forwards(tmp_path, capsys):
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    accepted = []
    threading.Thread(target=lambda: accepted.append(listener.accept()), daemon=True).start()
    path = write_filter(tmp_path, "flat")
    port = listener.getsockname()[1]
    status = cli.main(["serve", "--host", "127.0.0.1", "--port", "0", "--filter", str(path),
                       "--forward", f"127.0.0.1:{port}", "--exit-after", "1.2",
                       "--no-comparisons"])
    listener.close()
    out = capsys.readouterr().out
    assert status == 0 and accepted
    final = out.strip().splitlines()[-1]
    assert "yours flat.py running" in final
    assert f"forward 127.0.0.1:{port} connected, 0 lines sent" in final
