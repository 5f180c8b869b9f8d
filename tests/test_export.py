"""Exports: each format written, read back and compared with what the replay computes; the
command's bad arguments are one line and exit status 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from waiting import wait_for_snapshot

import ekf
from ekf.simulate import simulate
from app.cli import main
from app.engine.offline.export import (MAT_STRUCTS, csv_header, export_session, load_session,
                                       open_session, session_pieces, write_csv)
from app.engine.offline.matfile import check_size
from app.stream.demo import write_session
from app.engine.offline.filtering import filter_log
from app.engine.processing.runner import Rows
from app.engine.live.worker import Engine
from app.stream.logfile import read_log
from app.stream.protocol import Sample, format_line
from app.stream.sources import LogFileSource

SAMPLES_PER_S = 350


@pytest.fixture(scope="module")
def session_folder(tmp_path_factory) -> Path:
    """A recorded session: 20 s, the magnetometer switched out from 6 s to 12 s, two markers."""
    folder = tmp_path_factory.mktemp("exports") / "session"
    folder.mkdir()
    data = simulate(duration_s=20.0, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                               "ori": 100.0}, seed=21)
    (folder / "raw.txt").write_bytes(b"".join(
        (format_line(Sample(t, tag, values)) + "\n").encode() for t, tag, values in
        data.iter_rows()))
    timeline = [{"kind": "sensor", "sensor": "mag", "enabled": False, "t_ms": None,
                 "sample": 6 * SAMPLES_PER_S},
                {"kind": "sensor", "sensor": "mag", "enabled": True, "t_ms": None,
                 "sample": 12 * SAMPLES_PER_S},
                {"kind": "marker", "id": 1, "label": "mag out", "t_s": 6.0, "t_ms": None},
                {"kind": "marker", "id": 2, "label": "mag in", "t_s": 12.0, "t_ms": None}]
    (folder / "session.json").write_text(json.dumps({"format": 2, "timeline": timeline}))
    return folder


def _read_csv(path: Path, separator: str = ",", decimal_comma: bool = False) -> np.ndarray:
    lines = path.read_text().splitlines()
    assert lines[0] == csv_header(separator)
    rows = []
    for line in lines[1:]:
        fields = line.split(separator)
        if decimal_comma:
            fields = [f.replace(",", ".") for f in fields]
        rows.append([float(f) if f else np.nan for f in fields])
    return np.array(rows)


def _replayed(folder: Path) -> Rows:
    engine = Engine(LogFileSource(folder / "raw.txt", speed=0), record_rows=True, index=False,
                    comparisons=False)
    with engine:
        wait_for_snapshot(engine, lambda s: s.health.connection_state == "finished", 30,
                          "the replay to finish")
    rows = Rows.concatenate(engine.rows_log)
    return rows.select(rows.has_sample)


def test_csv_holds_what_the_replay_computes(session_folder, tmp_path):
    out = tmp_path / "all.csv"
    message = export_session(session_folder, "csv", out)
    assert message.startswith(f"{out}: ") and "rows" in message
    table = _read_csv(out)
    data = load_session(session_folder)
    assert table.shape == (len(data), 27)
    np.testing.assert_allclose(table[:, 0], data.t_s, atol=5e-4)
    np.testing.assert_allclose(table[:, 1:4], data.acc, rtol=1e-8, equal_nan=True)
    np.testing.assert_allclose(table[:, 7:10], data.mag, rtol=1e-8, equal_nan=True)
    # our quaternion: the replay's (the recorded timeline applied), rows with a sensor sample
    replay = _replayed(session_folder)
    has_sensor = ~np.isnan(table[:, 1:10]).all(axis=1)
    np.testing.assert_allclose(table[has_sensor, 14:18], replay.quat, atol=1e-9)
    # the timeline made a difference: the plain log's estimates are not these
    plain = filter_log(read_log(session_folder / "raw.txt"))
    assert np.abs(plain.quat - replay.quat).max() > 1e-3
    euler = np.degrees(ekf.quaternion.to_euler(data.quat))      # (not from the rounded q:
    np.testing.assert_allclose(table[:, 18:21], euler, atol=1e-5)   # gimbal lock is near)
    assert set(np.unique(table[:, 24:27])) <= {0.0, 1.0}


def test_csv_between_markers_with_a_decimal_comma(session_folder, tmp_path):
    out = tmp_path / "part.csv"
    assert main(["export", str(session_folder), "--format", "csv", "-o", str(out),
                 "--from-marker", "mag out", "--to-marker", "2", "--decimal-comma"]) == 0
    table = _read_csv(out, ";", decimal_comma=True)
    assert 5.99 <= table[0, 0] and table[-1, 0] <= 12.01 and len(table) > 500
    whole = _read_csv(_export(session_folder, tmp_path, "csv"))
    chosen = (whole[:, 0] >= table[0, 0]) & (whole[:, 0] <= table[-1, 0])
    np.testing.assert_allclose(table, whole[chosen], rtol=1e-8, equal_nan=True)


def test_log_export_is_the_phone_format_verbatim(session_folder, tmp_path):
    out = _export(session_folder, tmp_path, "log")
    assert out.read_bytes() == (session_folder / "raw.txt").read_bytes()
    part = tmp_path / "part.txt"
    export_session(session_folder, "log", part, from_s=5.0, to_s=8.0)
    raw = (session_folder / "raw.txt").read_bytes()
    assert raw.find(part.read_bytes()) > 0
    times = read_log(part).t_ms            # the course's reader's format: it reads
    first = read_log(session_folder / "raw.txt").t_ms[0]
    assert (times - first).min() >= 4990 and (times - first).max() <= 8010


def test_mat_export_has_meas_and_xhat_as_filter_template(session_folder, tmp_path):
    scipy_io = pytest.importorskip("scipy.io")
    out = _export(session_folder, tmp_path, "mat")
    mat = scipy_io.loadmat(out, simplify_cells=True)
    meas, xhat = mat["meas"], mat["xhat"]
    count = len(load_session(session_folder))
    assert meas["t"].shape == (count,) and meas["acc"].shape == (3, count)
    assert meas["orient"].shape == (4, count) and xhat["P"].shape == (4, 4, count)
    assert np.isnan(meas["mag"]).all(axis=0).sum() > count / 3       # MAG at half the rate
    replay = _replayed(session_folder)
    has_sensor = ~np.isnan(np.vstack([meas["acc"], meas["gyr"], meas["mag"]])).all(axis=0)
    np.testing.assert_array_equal(xhat["x"][:, has_sensor].T, replay.quat)
    covariance = np.transpose(xhat["P"], (2, 0, 1))[100:]
    np.testing.assert_allclose(covariance, np.transpose(covariance, (0, 2, 1)), atol=1e-12)
    assert (np.linalg.eigvalsh(covariance) > -1e-12).all()


def _export(folder: Path, tmp_path: Path, fmt: str) -> Path:
    out = tmp_path / f"whole.{ {'csv': 'csv', 'log': 'txt', 'mat': 'mat'}[fmt] }"
    export_session(folder, fmt, out)
    return out


@pytest.mark.parametrize("arguments, message", [
    (["--format", "csv", "--from-marker", "nope"], "no marker 'nope'"),
    (["--format", "csv", "--decimal-comma", "--separator", "comma"], "decimal comma needs"),
    (["--format", "csv", "--from", "9", "--to", "3"], "ends (3.000 s) before it starts"),
    (["--format", "csv", "--from", "100", "--to", "200"], "no samples from 100.000 s to 200.000"),
    (["--format", "xls"], "invalid choice"),
])
def test_bad_export_arguments_are_one_line_and_exit_2(session_folder, tmp_path, capsys,
                                                      arguments, message):
    out = tmp_path / "x.out"
    with pytest.raises(SystemExit) if "xls" in arguments else _nothing():
        assert main(["export", str(session_folder), "-o", str(out), *arguments]) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1 and "Traceback" not in error


def test_exporting_a_missing_or_foreign_file_names_it(tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("milk\neggs\n")
    for path, expected in ((tmp_path / "missing", "no such file"),
                           (notes, "not a phone log or recorded session")):
        assert main(["export", str(path), "--format", "csv", "-o", str(tmp_path / "o")]) == 2
        error = capsys.readouterr().err
        assert str(path) in error and expected in error and len(error.strip().splitlines()) == 1


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize("command", ["export", "filter"])
def test_no_command_writes_over_its_input_or_into_a_session(session_folder, tmp_path, capsys,
                                                            command):
    before = {p.name: p.read_bytes() for p in session_folder.iterdir() if p.is_file()}
    raw = session_folder / "raw.txt"
    extra = ["--format", "csv"] if command == "export" else []
    source = session_folder if command == "export" else raw
    for out in (session_folder / "session.json", raw, session_folder / "new.csv"):
        assert main([command, str(source), *extra, "-o", str(out)]) == 2
        error = capsys.readouterr().err
        assert len(error.strip().splitlines()) == 1 and "never written over" in error, error
    assert {p.name: p.read_bytes() for p in session_folder.iterdir() if p.is_file()} == before


def test_a_failed_export_leaves_the_old_file_whole(session_folder, tmp_path, monkeypatch):
    out = tmp_path / "keep.csv"
    out.write_text("my own file\n")
    import app.engine.offline.export as export

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(export, "csv_header", fail)
    with pytest.raises(export.ConfigError) as error:
        export_session(session_folder, "csv", out)
    assert "No space left" in str(error.value)
    assert out.read_text() == "my own file\n"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.csv"]      # no partial file beside
    monkeypatch.undo()
    export_session(session_folder, "csv", out)
    assert out.read_text().startswith(csv_header())


# ---- as a stream -------------------------------------------------------------------------------

@given(block_bytes=st.integers(2048, 400_000))
@hsettings(max_examples=5, deadline=None,
           suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_exports_do_not_depend_on_the_blocks_the_log_is_read_in(session_folder, tmp_path,
                                                                 block_bytes):
    """The session is replayed block by block and each block's rows written as they come: any
    block size gives the session computed whole, and the same files."""
    opened = open_session(session_folder)
    whole = load_session(session_folder, with_cov=True)
    pieces = list(session_pieces(opened, with_cov=True, block_bytes=block_bytes))
    for name in ("t_ms", "t_s", "gyr", "acc", "mag", "ori", "quat", "flags", "cov"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in pieces]),
                                      getattr(whole, name), err_msg=name)
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    start, end = 3.0, 15.5
    assert write_csv(iter(pieces), a, start, end, ";", True) == \
        write_csv(iter([whole]), b, start, end, ";", True)
    assert a.read_bytes() == b.read_bytes()


def test_the_mat_export_holds_what_scipy_savemat_would_write(session_folder, tmp_path):
    scipy_io = pytest.importorskip("scipy.io")
    out = _export(session_folder, tmp_path, "mat")
    data = load_session(session_folder, with_cov=True)
    reference = tmp_path / "reference.mat"
    t = data.t_s[None, :]
    scipy_io.savemat(reference, {
        "meas": {"t": t, "acc": data.acc.T, "gyr": data.gyr.T, "mag": data.mag.T,
                 "orient": data.ori.T},
        "xhat": {"t": t, "x": data.quat.T, "P": np.transpose(data.cov, (1, 2, 0))}},
        oned_as="row", do_compression=True)
    ours, theirs = (scipy_io.loadmat(p, simplify_cells=True) for p in (out, reference))
    for struct in ("meas", "xhat"):
        assert list(ours[struct]) == list(theirs[struct])
        for name in ours[struct]:
            np.testing.assert_array_equal(ours[struct][name], theirs[struct][name])


def test_a_mat_variable_over_2_gib_is_refused_before_anything_is_written():
    check_size(MAT_STRUCTS, 10_000_000)                        # 1.6 GiB of xhat: fits
    with pytest.raises(ValueError, match="at most 2 GiB a variable"):
        check_size(MAT_STRUCTS, 13_000_000)


def test_a_log_whose_clock_restarts_exports_the_estimates_of_both_sessions(tmp_path):
    """Was: the rows of every session but the last were dropped where the clock restarted,
    and the earlier times took the estimates of other rows."""
    first, second, log = (tmp_path / name for name in ("a.txt", "b.txt", "ab.txt"))
    write_session(simulate(duration_s=6.0, seed=1, t0_ms=1_000_000), first)
    write_session(simulate(duration_s=6.0, seed=2, t0_ms=50_000_000), second)
    log.write_bytes(first.read_bytes() + second.read_bytes())
    out = tmp_path / "ab.csv"
    export_session(log, "csv", out)
    table = _read_csv(out)
    rows = filter_log(read_log(log))
    has_sensor = ~np.isnan(table[:, 1:10]).all(axis=1)
    assert has_sensor.sum() == len(rows)
    np.testing.assert_allclose(table[has_sensor, 14:18], rows.quat, atol=1e-8)
