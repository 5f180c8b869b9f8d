"""Your filter never stalls anything (issue 46, items 2 and 10): it runs in a process of its own.
A step that never returns (time.sleep, input(), at import), a crash of its process, a filter
that forks or closes its stdout: the phone link, the recording, OWN and the command line go on,
YOURS is paused with the reason, and what it started is ended with it."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from waiting import wait_for_snapshot, wait_until

import app.engine.userfilter.remote as remote
from app import cli
from app.engine.config import open_log
from app.engine.offline.filtering import filter_log
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.sources import LogFileSource
from user_filters import FILTERS, log_lines, save_again, write_filter

REPO = Path(__file__).resolve().parents[1]
POSIX = pytest.mark.skipif(os.name != "posix", reason="process groups, signals: POSIX")

STUCK = {
    # time.sleep(3600) in step on its 100th call (line 9)
    "sleeps": """
        import time
        class Filter:
            def __init__(self):
                self.calls = 0
            def step(self, t, gyr, acc, mag):
                self.calls += 1
                if self.calls == 100:
                    time.sleep(3600)
                return [1.0, 0.0, 0.0, 0.0]
    """,
    # input() in step on its 100th call (line 8): no keyboard, an error at once
    "asks": """
        class Filter:
            def __init__(self):
                self.calls = 0
            def step(self, t, gyr, acc, mag):
                self.calls += 1
                if self.calls == 100:
                    input("gate? ")
                return [1.0, 0.0, 0.0, 0.0]
    """,
    # time.sleep(3600) while the file loads (line 3)
    "sleeps_at_import": """
        import time
        time.sleep(3600)
        class Filter:
            def step(self, t, gyr, acc, mag):
                return [1.0, 0.0, 0.0, 0.0]
    """,
}
EXPECTED = {
    "sleeps": ("paused", "your filter has not returned from step for {deadline:g} s "
               "(sleeps.py:9 in step): paused; save the file to reload"),
    "asks": ("paused", "asks.py:8 in step: EOFError: a filter has no keyboard: input() and "
             "sys.stdin are not available"),
    "sleeps_at_import": ("failed to load", "your filter has not finished loading for "
                         "{load_deadline:g} s (sleeps_at_import.py:3 in <module>)"),
}
ENDS = {
    "exits": """
        import os
        class Filter:
            calls = 0
            def step(self, t, gyr, acc, mag):
                Filter.calls += 1
                if Filter.calls == 50:
                    os._exit(3)
                return [1.0, 0.0, 0.0, 0.0]
    """,
    "segfaults": """
        import ctypes
        class Filter:
            calls = 0
            def step(self, t, gyr, acc, mag):
                Filter.calls += 1
                if Filter.calls == 50:
                    ctypes.string_at(0)          # reads address 0: SIGSEGV
                return [1.0, 0.0, 0.0, 0.0]
    """,
}


@pytest.fixture
def short_deadlines(monkeypatch):
    """Deadlines of a second: the tests wait for them."""
    monkeypatch.setattr(remote, "DEADLINE_S", 1.0)
    monkeypatch.setattr(remote, "LOAD_DEADLINE_S", 1.5)
    return {"deadline": 1.0, "load_deadline": 1.5}


def _log(tmp_path: Path, seconds: float = 6.0) -> Path:
    path = tmp_path / "log.txt"
    path.write_bytes(b"".join(log_lines(seconds)))
    return path


def _finished(snapshot) -> bool:
    return snapshot.health.connection_state == "finished"


def _wait(engine, predicate, timeout: float = 30.0):
    return wait_for_snapshot(engine, predicate, timeout, describe=lambda s: f"user: {s.user}")


def _gone(pid: int) -> bool:
    """The process ended (a zombie nobody reaps counts as ended)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return False


def _own_rows(engine) -> tuple[np.ndarray, np.ndarray]:
    rows = engine.rows_log
    return (np.concatenate([r.t_ms for r in rows]),
            np.concatenate([r.quat[r.has_sample] for r in rows]))


# ---- the window's engine -----------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(STUCK))
def test_a_filter_stuck_in_its_code_pauses_yours_and_the_engine_goes_on(tmp_path, name,
                                                                        short_deadlines):
    log = _log(tmp_path)                         # 600 rows, replayed in 3 s
    path = write_filter(tmp_path, name, STUCK[name])
    engine = Engine(LogFileSource(log, speed=2), comparisons=False, record_rows=True,
                    user_filter=path)
    state, message = EXPECTED[name]
    with engine:
        final = _wait(engine, lambda s: _finished(s) and s.user is not None
                      and s.user.state == state)
        # OWN went on to the end of the log, exactly as without your filter
        t_ms, quat = _own_rows(engine)
        assert len(t_ms) == 600 and final.health.lines_total == len(log_lines(6.0))
        assert np.array_equal(quat, filter_log(open_log(log)).quat)
        assert message.format(**short_deadlines) in final.user.problem.message
        assert not engine.failures
        # saving the file again loads it in a new process: YOURS runs again
        save_again(path, FILTERS["turned"])
        # (an editor may write the file in two goes: each save loads it again)
        _wait(engine, lambda s: s.user.generation >= 2 and s.user.state == "running")


def test_a_stuck_filter_is_killed_with_what_it_started_on_reload_and_exit(tmp_path,
                                                                          short_deadlines):
    pids = tmp_path / "pids"
    path = write_filter(tmp_path, "stuck", f"""
        import os, time
        class Filter:
            def step(self, t, gyr, acc, mag):
                if os.fork() == 0:                 # a process it starts, that sleeps too
                    open({str(pids)!r}, "a").write(f"{{os.getpid()}}\\n")
                    time.sleep(3600)
                open({str(pids)!r}, "a").write(f"{{os.getpid()}}\\n")
                time.sleep(3600)
    """)
    engine = Engine(LogFileSource(_log(tmp_path, 2.0), speed=4), comparisons=False,
                    user_filter=path)
    with engine:
        _wait(engine, lambda s: s.user is not None and s.user.state == "paused")
        first = wait_until(lambda: pids.is_file() and len(pids.read_text().split()) == 2
                           and [int(p) for p in pids.read_text().split()], what="both pids")
        assert not any(_gone(pid) for pid in first)    # paused: left as it is until reloaded
        pids.unlink()
        save_again(path, Path(path).read_text())
        second = wait_until(lambda: pids.is_file() and len(pids.read_text().split()) == 2
                            and [int(p) for p in pids.read_text().split()], what="new pids")
        wait_until(lambda: all(_gone(pid) for pid in first), 10, "the first ones to end")
    assert all(_gone(pid) for pid in second)             # the engine stopped: ended too


@POSIX
@pytest.mark.parametrize("name, reason", [("exits", "exit status 3"),
                                          ("segfaults", "signal 11, SIGSEGV")])
def test_a_crash_of_your_filters_process_pauses_yours_with_the_reason(tmp_path, name, reason):
    log = _log(tmp_path, 3.0)
    engine = Engine(LogFileSource(log, speed=4), comparisons=False, record_rows=True,
                    user_filter=write_filter(tmp_path, name, ENDS[name]))
    with engine:
        final = _wait(engine, lambda s: _finished(s) and s.user is not None
                      and s.user.state == "paused")
        t_ms, quat = _own_rows(engine)
    problem = final.user.problem
    assert problem.kind == "ended" and problem.message == (
        f"{name}.py: your filter ended the process it runs in ({reason}: os._exit() or a crash "
        "in its code): paused; save the file to reload")
    assert 1.35 <= problem.t_s <= 1.49                  # the 50th row (or its block's first)
    assert len(t_ms) == 300 and np.array_equal(quat, filter_log(open_log(log)).quat)
    assert not engine.failures


def test_a_filter_that_closes_its_stdout_harms_nothing_but_its_own_prints(tmp_path):
    path = write_filter(tmp_path, "closes", """
        import os
        class Filter:
            calls = 0
            def step(self, t, gyr, acc, mag):
                Filter.calls += 1
                if Filter.calls == 1:
                    os.close(1)
                if Filter.calls == 200:
                    print("done")
                return [1.0, 0.0, 0.0, 0.0]
    """)
    engine = Engine(LogFileSource(_log(tmp_path, 3.0), speed=4), comparisons=False,
                    user_filter=path)
    with engine:
        final = _wait(engine, lambda s: _finished(s) and s.user is not None
                      and s.user.state == "paused")
    assert final.user.steps == 200 and final.user.problem.message.startswith(
        "closes.py:10 in step: OSError: [Errno 9] Bad file descriptor")


def test_what_your_filter_prints_reaches_the_status_and_the_log(tmp_path, caplog):
    path = write_filter(tmp_path, "chatty", """
        class Filter:
            calls = 0
            def step(self, t, gyr, acc, mag):
                Filter.calls += 1
                print("call", Filter.calls)
                return [1.0, 0.0, 0.0, 0.0]
    """)
    caplog.set_level("INFO", logger="orientation_lab.your_filter")
    engine = Engine(LogFileSource(_log(tmp_path, 3.0), speed=0), comparisons=False,
                    user_filter=path)
    with engine:
        final = _wait(engine, lambda s: _finished(s) and s.user is not None
                      and s.user.printed_total == 300)
    assert final.user.printed == [f"call {k}" for k in range(281, 301)]   # the last 20
    logged = [r.getMessage() for r in caplog.records if r.name == "orientation_lab.your_filter"]
    assert logged[0] == "chatty.py: call 1" and 20 <= len(logged) < 300   # at most 20 a second


# ---- the command line ----------------------------------------------------------------------

@POSIX
def test_filter_does_not_wait_for_what_your_filter_forks(tmp_path, capsys):
    pids = tmp_path / "pids"
    path = write_filter(tmp_path, "forks", f"""
        import os, time
        class Filter:
            calls = 0
            def step(self, t, gyr, acc, mag):
                Filter.calls += 1
                if Filter.calls == 1 and os.fork() == 0:   # keeps running, holding the pipes
                    open({str(pids)!r}, "w").write(str(os.getpid()))
                    time.sleep(3600)
                if Filter.calls == 2:
                    os.fork()       # both return into the filter's process: the copy ends
                return [1.0, 0.0, 0.0, 0.0]
    """)
    log = _log(tmp_path, 3.0)
    out = tmp_path / "o.csv"
    assert cli.main(["filter", str(log), "--estimator", str(path), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "ended the process" not in err and "Traceback" not in err
    assert out.read_text().count("\n") == 301
    assert _gone(int(pids.read_text()))                  # what it started ended with it


@POSIX
@pytest.mark.parametrize("name, needle", [
    ("exits", "your filter stopped: exits.py: your filter ended the process it runs in "
              "(exit status 3: os._exit() or a crash in its code)"),
    ("segfaults", "(signal 11, SIGSEGV: os._exit() or a crash in its code)"),
])
def test_filter_says_your_filter_crashed_and_exits_1(tmp_path, capsys, name, needle):
    path = write_filter(tmp_path, name, ENDS[name])
    out = tmp_path / "o.csv"
    assert cli.main(["filter", str(_log(tmp_path, 3.0)), "--estimator", str(path), "-o",
                     str(out)]) == 1
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and not out.exists()


def test_filter_with_a_stuck_filter_ends_with_one_line(tmp_path, capsys, short_deadlines):
    path = write_filter(tmp_path, "sleeps", STUCK["sleeps"])
    assert cli.main(["filter", str(_log(tmp_path, 3.0)), "--estimator", str(path)]) == 1
    err = capsys.readouterr().err
    assert ("orientation-lab: your filter stopped: your filter has not returned from step for "
            "1 s (sleeps.py:9 in step)") in err
    path = write_filter(tmp_path, "sleeps_at_import", STUCK["sleeps_at_import"])
    assert cli.main(["filter", str(_log(tmp_path, 3.0)), "--estimator", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has not finished loading for 1.5 s" in err


# ---- serve --record --------------------------------------------------------------------------

SERVE_CASES = {
    "sleeps": (STUCK["sleeps"], "yours sleeps.py paused"),
    "asks": (STUCK["asks"], "yours asks.py paused"),
    "sleeps_at_import": (STUCK["sleeps_at_import"], "yours sleeps_at_import.py failed to load"),
    "closes": ("""
        import os
        class Filter:
            closed = False
            def step(self, t, gyr, acc, mag):
                if not Filter.closed:
                    os.close(1)
                    os.close(2)
                    Filter.closed = True
                return [1.0, 0.0, 0.0, 0.0]
    """, "yours closes.py running"),
}


@POSIX
@pytest.mark.parametrize("name", sorted(SERVE_CASES))
def test_serve_records_every_line_whatever_your_filter_does(tmp_path, name):
    body, state = SERVE_CASES[name]
    path = write_filter(tmp_path, name, body)
    folder = tmp_path / "rec"
    lines = log_lines(21.0)[:7200]
    env = dict(os.environ, ORIENTATION_LAB_DATA=str(tmp_path / "data"))
    # stdin: a pipe that stays open and silent, as a terminal nobody types into
    process = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", "0",
         "--record", str(folder), "--filter", str(path), "--no-comparisons"],
        cwd=REPO, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    health: list[str] = []
    try:
        port = int(re.search(r"port (\d+)", process.stdout.readline()).group(1))
        reader = threading.Thread(target=lambda: health.extend(process.stdout), daemon=True)
        reader.start()
        with PhoneEmulator("127.0.0.1", port) as phone:
            phone.stream_lines(lines, speed=8.0)
            wait_until(lambda: any("7200 lines" in line and state in line for line in health),
                       40, f"'{state}' after all lines; health: {health[-1:]}")
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=20)
        reader.join(10)
    finally:
        if process.poll() is None:
            process.kill()
        _, err = process.communicate(timeout=10)
    assert process.returncode == 0 and "Traceback" not in err, err
    assert (folder / "raw.txt").read_bytes() == b"".join(lines)     # every phone line
    session = json.loads((folder / "session.json").read_text())
    assert session["stopped_utc"] is not None                        # finalised
    assert [e["action"] for e in session["timeline"] if e["kind"] == "user_filter"][0] == "load"
    assert health[-1].startswith("final: ") and "7200 lines" in health[-1]
