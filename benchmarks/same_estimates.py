"""Fingerprints of every estimate the command line gives on the shared recordings.

A change that should not move any estimate (a refactor, a module split, a faster path) is
checked by writing the fingerprints before it and comparing after::

    .venv/bin/python benchmarks/same_estimates.py --write /tmp/before.json
    # ... the change ...
    .venv/bin/python benchmarks/same_estimates.py --compare /tmp/before.json

Every phone log under ``../shared/data`` (``*.txt``, not the ``*.truth.txt`` optical truth)
is filtered through ``orientation-lab filter`` in this process with each variant below, and
the SHA-256 of the output CSV is recorded; a log the command refuses is recorded by its exit
status and message, so a change in what is refused shows too. ``--compare`` prints every
variant whose output differs and exits 1 when any does.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cli import main as cli_main  # noqa: E402

DATA = ROOT.parent / "shared" / "data"

VARIANTS: dict[str, list[str]] = {
    "ekf": [],
    "ekf-gyr-acc": ["--sensors", "gyr,acc"],
    "ekf-smooth": ["--smooth"],
    "course": ["--estimator", "course"],
    "complementary": ["--estimator", "complementary"],
}


def logs(data: Path) -> list[Path]:
    return sorted(p for p in data.rglob("*.txt") if not p.name.endswith(".truth.txt"))


def fingerprint(log: Path, extra: list[str], out: Path) -> str:
    out.unlink(missing_ok=True)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = cli_main(["filter", str(log), *extra, "-o", str(out)])
    if rc != 0 or not out.exists():
        return f"exit {rc}: {err.getvalue().strip()}"
    return hashlib.sha256(out.read_bytes()).hexdigest()


def run(data: Path, only: str | None) -> dict[str, str]:
    found = logs(data)
    if not found:
        raise SystemExit(f"no phone logs under {data}")
    result: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "estimates.csv"
        for log in found:
            name = str(log.relative_to(data))
            if only and only not in name:
                continue
            started = time.perf_counter()
            for variant, extra in VARIANTS.items():
                result[f"{name} [{variant}]"] = fingerprint(log, extra, out)
            print(f"{name}: {time.perf_counter() - started:.1f} s", file=sys.stderr)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--write", type=Path, metavar="FILE.json",
                      help="write the fingerprints to FILE.json")
    what.add_argument("--compare", type=Path, metavar="FILE.json",
                      help="compare with fingerprints written before")
    parser.add_argument("--data", type=Path, default=DATA,
                        help=f"recordings folder (default {DATA})")
    parser.add_argument("--only", help="only logs whose path contains this text")
    args = parser.parse_args()
    result = run(args.data, args.only)
    if args.write:
        args.write.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
        print(f"{len(result)} estimates written to {args.write}")
        return 0
    before = json.loads(args.compare.read_text())
    differ = [key for key in result if before.get(key) != result[key]]
    missing = [key for key in before if key not in result and not args.only]
    for key in differ:
        print(f"differs: {key}\n  before {before.get(key)}\n  after  {result[key]}")
    for key in missing:
        print(f"missing: {key}")
    same = len(result) - len(differ)
    print(f"{same} of {len(result)} estimates identical"
          + (f"; {len(missing)} missing" if missing else ""))
    return 1 if differ or missing else 0


if __name__ == "__main__":
    raise SystemExit(main())
