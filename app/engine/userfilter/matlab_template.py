"""The MATLAB filter template that ``orientation-lab new-filter --matlab DIR`` writes: the
course's functions for tasks 4, 6, 8, 9 and 11 and the normalisation as documented functions that
say they are not written yet, ``filter_settings.m``, the kit's helpers (appendix A.2, ``Somega``'s
row 3 as eq. 2d has it) and a README in MATLAB terms. The files live in ``matlab_template/``.
"""

from __future__ import annotations

from pathlib import Path

TEMPLATE_DIR = Path(__file__).resolve().with_name("matlab_template")


def template_files() -> list[Path]:
    """The template's files, by name."""
    return sorted((p for p in TEMPLATE_DIR.iterdir() if p.suffix in (".m", ".md")),
                  key=lambda p: p.name)


def write_matlab_template(folder: str | Path) -> Path:
    """Write the template into `folder` (made if it does not exist). FileExistsError naming the
    files when any of them exists already (a file of the user's is never overwritten);
    NotADirectoryError when `folder` is a file; OSError when it cannot be written."""
    folder = Path(folder).expanduser()
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(f"{folder} is a file, not a folder")
    files = template_files()
    there = [p.name for p in files if (folder / p.name).exists()]
    if there:
        raise FileExistsError(f"{folder} has {', '.join(there)} already")
    folder.mkdir(parents=True, exist_ok=True)
    for source in files:
        with open(folder / source.name, "xb") as stream:      # "x": never overwrite
            stream.write(source.read_bytes())
    return folder
