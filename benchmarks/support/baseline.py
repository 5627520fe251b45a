"""Another git revision's `calib_free`, importable beside the working tree's: a benchmark
measures a change against the code before it on the same inputs in the same run, so that the
machine's load touches both alike."""
from __future__ import annotations

import importlib
import io
import re
import subprocess
import sys
import tarfile
import tempfile
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_EXTRACTED: dict[str, Path] = {}  # revision -> its package, extracted once a process


def baseline_package(rev: str) -> Path:
    """The revision `rev`'s whole `calib_free` package, extracted to a temporary folder as
    `calib_free_baseline` (its own imports renamed to match) and put on `sys.path`: its modules
    run with their own kernels and helpers. Returns the package's folder. One revision a
    process: there is one `calib_free_baseline`."""
    if rev in _EXTRACTED:
        return _EXTRACTED[rev]
    if _EXTRACTED:
        raise ValueError(f"baseline {rev}: this process already imported {next(iter(_EXTRACTED))}'s")
    archive = subprocess.run(["git", "archive", rev, "calib_free"], cwd=ROOT, check=True, capture_output=True).stdout
    folder = Path(tempfile.mkdtemp(prefix="bench-baseline-"))
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    package = folder / "calib_free_baseline"
    (folder / "calib_free").rename(package)
    for source in package.rglob("*.py"):
        source.write_text(re.sub(r"\bcalib_free\b", "calib_free_baseline", source.read_text()))
    sys.path.insert(0, str(folder))  # the other revision's tree: importable only from where it was extracted
    _EXTRACTED[rev] = package
    return package


def baseline_module(rev: str, module: str) -> types.ModuleType:
    """`calib_free.<module>` as it is at revision `rev` (`baseline_package`)."""
    baseline_package(rev)
    return importlib.import_module(f"calib_free_baseline.{module}")
