"""Output paths (issue 46 item 1, issue 51's -o rule): a regular or new file is replaced
whole, a character device or a FIFO is written into and never replaced, a symbolic link is
followed, a write error is one line with exit status 2; as root and as a normal user."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pwd
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest

from app import cli
from app.engine.errors import ConfigError
from app.engine.offline.outputs import check_output, open_output, write_output
from app.stream.demo import write_session
from ekf.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
FULL = Path("/dev/full")


def _root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture
def full(tmp_path) -> Path:
    """A device on which every write fails with ENOSPC: as root a copy of /dev/full's node
    (character device 1, 7) in tmp_path, so that code which replaces what it writes (the bug
    under test) never replaces the system's; otherwise /dev/full itself."""
    if _root():
        node = tmp_path / "full"
        os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
        return node
    if not FULL.is_char_device():
        pytest.skip("no /dev/full here")
    return FULL


def _is_full_device(path: Path) -> bool:
    info = os.lstat(path)
    return stat.S_ISCHR(info.st_mode) and info.st_rdev == os.makedev(1, 7)


ROOT_ONLY = pytest.mark.skipif(not _root(), reason="needs root: mknod, and setpriv to run as "
                                                   "another user")


def _null_device(folder: Path) -> Path:
    """A copy of /dev/null's node (character device 1, 3) in `folder`."""
    node = folder / "null"
    os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    return node


def _is_null_device(path: Path) -> bool:
    info = os.lstat(path)
    return stat.S_ISCHR(info.st_mode) and info.st_rdev == os.makedev(1, 3)


class FifoReader(threading.Thread):
    """Reads a FIFO to its end (or, `close_at_once`, opens it and closes it unread)."""

    def __init__(self, path: Path, close_at_once: bool = False) -> None:
        super().__init__(daemon=True)
        self.path, self.close_at_once = path, close_at_once
        self.data = b""

    def run(self) -> None:
        with open(self.path, "rb") as fifo:
            if not self.close_at_once:
                self.data = fifo.read()


@contextlib.contextmanager
def reading(path: Path, close_at_once: bool = False):
    reader = FifoReader(path, close_at_once)
    reader.start()
    try:
        yield reader
    finally:
        if reader.is_alive():           # a writer that never came: release the reader
            with contextlib.suppress(OSError):
                os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
        reader.join(timeout=60)
        assert not reader.is_alive()


# ---- the rule, path by path ---------------------------------------------------------------

def test_a_regular_file_is_replaced_whole_keeping_its_mode(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    target.chmod(0o640)
    inode = target.stat().st_ino
    write_output(target, "new\n")
    assert target.read_text() == "new\n"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert target.stat().st_ino != inode                       # renamed into place
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]  # no temporary left


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError):
        with open_output(target) as stream:
            stream.write("half")
            raise RuntimeError("the computation failed")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]


def test_a_new_file_gets_the_umask_permissions(tmp_path):
    mask = os.umask(0o027)
    try:
        write_output(tmp_path / "new.csv", "x\n")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o640


def test_a_symlink_is_followed_and_stays_a_symlink(tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target.name)
    write_output(link, "new\n")
    assert link.is_symlink() and os.readlink(link) == "real.csv"
    assert target.read_text() == "new\n"


def test_a_dangling_symlink_gets_its_target_created(tmp_path):
    link = tmp_path / "link.csv"
    link.symlink_to("made.csv")
    write_output(link, "new\n")
    assert link.is_symlink() and (tmp_path / "made.csv").read_text() == "new\n"


def test_a_symlink_loop_is_one_line(tmp_path):
    (tmp_path / "a").symlink_to("b")
    (tmp_path / "b").symlink_to("a")
    with pytest.raises(ConfigError, match="cannot write .*a: Too many levels of symbolic links"):
        write_output(tmp_path / "a", "x")


def test_a_fifo_is_written_into_and_stays_a_fifo(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with reading(fifo) as reader:
        write_output(fifo, b"through the pipe\n" * 10_000)
    assert reader.data == b"through the pipe\n" * 10_000
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_a_fifo_closed_by_its_reader_is_one_line(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with reading(fifo, close_at_once=True):
        with pytest.raises(ConfigError, match="cannot write .*pipe: Broken pipe"):
            write_output(fifo, b"x" * (4 << 20))
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


@ROOT_ONLY
def test_a_character_device_is_written_into_never_replaced(tmp_path):
    node = _null_device(tmp_path)
    write_output(node, "discarded\n")
    assert _is_null_device(node)
    assert [p.name for p in tmp_path.iterdir()] == ["null"]


@ROOT_ONLY
def test_a_symlink_to_a_character_device_leaves_both(tmp_path):
    node = _null_device(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(node)
    write_output(link, "discarded\n")
    assert link.is_symlink() and _is_null_device(node)


def test_a_full_device_is_one_line(full):
    with pytest.raises(ConfigError, match=rf"^cannot write {full}: No space left on device$"):
        write_output(full, "x" * 100_000)
    assert _is_full_device(full)


def test_a_folder_a_socket_and_a_missing_folder_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="is a folder"):
        check_output(tmp_path)
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(tmp_path / "sock"))
        with pytest.raises(ConfigError, match="is a socket"):
            check_output(tmp_path / "sock")
    with pytest.raises(ConfigError, match="cannot write .*: No such file or directory"):
        write_output(tmp_path / "missing" / "out.csv", "x")


@ROOT_ONLY
def test_a_block_device_is_refused(tmp_path):
    node = tmp_path / "loop"
    os.mknod(node, 0o600 | stat.S_IFBLK, os.makedev(7, 0))
    with pytest.raises(ConfigError, match="is a block device"):
        check_output(node)
    with pytest.raises(ConfigError, match="is a block device"):
        write_output(node, "x")
    assert stat.S_ISBLK(os.lstat(node).st_mode)


# ---- every command that writes a user's path -----------------------------------------------

@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("outputs")
    motion = folder / "motion.txt"
    write_session(simulate(duration_s=8, seed=3), motion)
    rest = folder / "rest.txt"
    write_session(simulate(duration_s=6, script="rest", seed=4), rest)
    turning = simulate(duration_s=30, seed=5)
    turning.mag.values = turning.mag.values + np.array([30.0, -25.0, 200.0])
    mag = folder / "turning.txt"
    write_session(turning, mag)
    return {"motion": motion, "rest": rest, "mag": mag}


COMMANDS = {
    "filter": ["filter", "{motion}", "-o", "{out}"],
    "export csv": ["export", "{motion}", "--format", "csv", "-o", "{out}"],
    "export log": ["export", "{motion}", "--format", "log", "-o", "{out}"],
    "export mat": ["export", "{motion}", "--format", "mat", "-o", "{out}"],
    "calibrate": ["calibrate", "{rest}", "-o", "{out}"],
    "calibrate-mag": ["calibrate-mag", "{mag}", "-o", "{out}"],
    "tune": ["tune", "{motion}", "--params", "acc_noise_cov", "--max-evals", "2", "--no-check",
             "-o", "{out}"],
    "simulate": ["simulate", "--duration", "2", "-o", "{out}"],
    "phyphox-experiment": ["phyphox-experiment", "-o", "{out}"],
}


def _run(command: str, logs: dict, out: Path, capsys) -> tuple[int, list[str]]:
    argv = [part.format(out=out, **logs) for part in COMMANDS[command]]
    capsys.readouterr()
    code = cli.main(argv)
    return code, capsys.readouterr().err.strip().splitlines()


def _stored(path: Path) -> bytes:
    data = path.read_bytes()
    if path.suffix == ".mat" or data.startswith(b"MATLAB"):
        return data[128:]        # the header holds the time it was written
    return data


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_replaces_a_file_and_writes_through_a_link(command, logs, tmp_path,
                                                                 capsys):
    target = tmp_path / "real"
    target.write_text("an older output\n")
    link = tmp_path / "link"
    link.symlink_to(target.name)
    code, err = _run(command, logs, link, capsys)
    assert code == 0, err
    assert link.is_symlink() and target.read_bytes() != b"an older output\n"
    fresh = tmp_path / "fresh"
    assert _run(command, logs, fresh, capsys)[0] == 0
    if command != "tune":               # the report holds the search's wall time
        assert _stored(fresh) == _stored(target)


@ROOT_ONLY
@pytest.mark.parametrize("command", list(COMMANDS))
def test_no_command_replaces_a_device_node(command, logs, tmp_path, capsys):
    """Was: as root `filter LOG -o /dev/null` deleted the /dev/null device node and left a
    regular file in its place."""
    node = _null_device(tmp_path)
    code, err = _run(command, logs, node, capsys)
    assert code == 0, err
    assert _is_null_device(node)
    assert [p.name for p in tmp_path.iterdir()] == ["null"]


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_full_disk_is_one_line_and_exit_2_for_every_command(command, logs, full, capsys):
    """Was: `-o /dev/full` exited 0 (as root, after replacing the node)."""
    code, err = _run(command, logs, full, capsys)
    assert code == 2
    assert err[-1] == f"orientation-lab: error: cannot write {full}: No space left on device"
    assert not any("Traceback" in line for line in err)
    assert _is_full_device(full)


@pytest.mark.parametrize("command", ["filter", "export csv", "export mat", "simulate"])
def test_every_command_writes_into_a_fifo(command, logs, tmp_path, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with reading(fifo) as reader:
        code, err = _run(command, logs, fifo, capsys)
    assert code == 0, err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    plain = tmp_path / "plain"
    assert _run(command, logs, plain, capsys)[0] == 0
    assert reader.data[128:] == plain.read_bytes()[128:]
    if command != "export mat":
        assert reader.data == plain.read_bytes()


def test_simulate_replaces_its_output_and_force_is_a_no_op_with_a_note(tmp_path, capsys):
    """Issue 51: one rule for every output; simulate refused an existing file without
    --force. --force is still accepted (scripts use it) and says it is not needed."""
    log = tmp_path / "sim.txt"
    log.write_text("an older simulation\n")
    assert cli.main(["simulate", "-o", str(log), "--duration", "2"]) == 0
    first = log.read_bytes()
    assert b"ACC" in first and capsys.readouterr().err == ""
    assert cli.main(["simulate", "-o", str(log), "--duration", "2", "--force"]) == 0
    assert log.read_bytes() == first
    assert "--force is no longer needed" in capsys.readouterr().err


def test_new_filter_never_replaces_a_file(tmp_path, capsys):
    mine = tmp_path / "mine.py"
    mine.write_text("# my work\n")
    assert cli.main(["new-filter", str(mine)]) == 2
    assert mine.read_text() == "# my work\n"
    assert "not overwritten" in capsys.readouterr().err


def test_the_windows_save_settings_follows_the_rule(tmp_path, full, qtbot):
    from app.engine.tuning.profiles import ProfileStore
    from app.ui.settings_panel import SettingsPanel
    panel = SettingsPanel(lambda command: None, store=ProfileStore(tmp_path / "profiles"))
    qtbot.addWidget(panel)
    target = tmp_path / "real.json"
    target.write_text("{}")
    link = tmp_path / "settings.json"
    link.symlink_to(target.name)
    inode = target.stat().st_ino
    panel.save_to(link)
    assert link.is_symlink() and json.loads(target.read_text())["g"] > 9
    assert target.stat().st_ino != inode                   # replaced whole, never half
    panel.save_to(full)
    assert panel.message.text() == f"cannot write {full}: No space left on device"
    assert _is_full_device(full)


# ---- as a normal user ---------------------------------------------------------------------

def _numba_cache_copy(into: Path) -> None:
    """The compiled kernels cached in the source tree, laid out as NUMBA_CACHE_DIR holds them,
    so a user who may not write the tree loads them instead of compiling them again."""
    for index in ROOT.glob("*/**/__pycache__/*.nbi"):
        if ".venv" in index.parts:
            continue
        source = index.parent.parent
        folder = into / f"{source.name}_{hashlib.sha1(str(source).encode()).hexdigest()}"
        folder.mkdir(parents=True, exist_ok=True)
        stem = index.name[:-len(".nbi")]
        for cached in index.parent.glob(stem + "*"):
            if cached.suffix in (".nbi", ".nbc"):
                shutil.copy2(cached, folder / cached.name)


@pytest.fixture(scope="module")
def nobody_folder(logs):
    """A folder a normal user (nobody) may use: the logs, a home, a numba cache."""
    folder = Path(tempfile.mkdtemp(prefix="outputs-nobody-"))
    try:
        for name, path in logs.items():
            shutil.copy(path, folder / path.name)
        (folder / "home").mkdir()
        _numba_cache_copy(folder / "numba")
        (folder / "readonly").mkdir()
        subprocess.run(["chown", "-R", "nobody:nogroup", str(folder)], check=True)
        folder.chmod(0o755)
        (folder / "readonly").chmod(0o555)
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _as_nobody(folder: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(folder / "home"),
           "NUMBA_CACHE_DIR": str(folder / "numba"), "QT_QPA_PLATFORM": "offscreen",
           "PYTHONPATH": str(ROOT)}
    return subprocess.run(["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups",
                           sys.executable, "-m", "app", *argv], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=600)


@ROOT_ONLY
@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs setpriv (util-linux)")
def test_as_a_normal_user(nobody_folder):
    """Was: as a normal user `-o /dev/null` failed with exit 2 (a temporary file in /dev)."""
    done = _as_nobody(nobody_folder, "filter", "motion.txt", "-o", os.devnull)
    assert done.returncode == 0, done.stderr
    assert Path(os.devnull).is_char_device()
    done = _as_nobody(nobody_folder, "filter", "motion.txt", "-o", "readonly/out.csv")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        "orientation-lab: error: cannot write readonly/out.csv: Permission denied")
    assert not any((nobody_folder / "readonly").iterdir())
    if FULL.is_char_device():
        done = _as_nobody(nobody_folder, "simulate", "--duration", "2", "-o", str(FULL))
        assert done.returncode == 2
        assert done.stderr.strip() == ("orientation-lab: error: cannot write /dev/full: No "
                                       "space left on device")
    done = _as_nobody(nobody_folder, "simulate", "--duration", "2", "-o", "mine.txt")
    assert done.returncode == 0, done.stderr
    assert (nobody_folder / "mine.txt").stat().st_uid == pwd.getpwnam("nobody").pw_uid


@ROOT_ONLY
def test_root_replacing_a_users_file_keeps_its_owner(tmp_path):
    target = tmp_path / "theirs.csv"
    target.write_text("old\n")
    nobody = pwd.getpwnam("nobody")
    os.chown(target, nobody.pw_uid, nobody.pw_gid)
    write_output(target, "new\n")
    assert (target.stat().st_uid, target.stat().st_gid) == (nobody.pw_uid, nobody.pw_gid)
