"""Where the files a problem names are found: the checkout, the installed package data,
example-robot-data.

Relative paths (URDFs, problem and evaluation files) are resolved against the repository root first
(a source checkout), then against the data the installed package ships (`robots/`, `problems/`),
then against the problem file's folder.
"""

from __future__ import annotations

import sysconfig
from pathlib import Path
from typing import Any

from .schema import Reader

REPO_ROOT = Path(__file__).resolve().parents[2]
# robots/ and problems/ as installed with the package (pyproject.toml maps them to
# surestep_ocp/data/*); in a source checkout (editable install) they are at REPO_ROOT instead
PACKAGE_DATA = Path(__file__).resolve().parents[1] / "data"


def data_roots() -> tuple[Path, ...]:
    """Folders that `robots/...` and `problems/...` are resolved against: the checkout, then the
    package data."""
    checkout = (REPO_ROOT / "pyproject.toml").is_file() and (REPO_ROOT / "robots").is_dir()
    roots = [REPO_ROOT] if checkout else []
    return tuple(roots + ([PACKAGE_DATA] if PACKAGE_DATA.is_dir() else []))



def find_shipped(path: str | Path) -> Path:
    """`path` itself when it exists, else a shipped file of that relative name
    (`problems/needle_regrasp.yaml` from any folder once the package is installed), else `path`
    unchanged (the caller reports it missing)."""
    path = Path(path)
    if path.is_file() or path.is_absolute():
        return path
    for root in data_roots():
        if (root / path).is_file():
            return root / path
    return path



ERD_PREFIX = "example-robot-data:"


def example_robot_data_dir() -> Path:
    """Folder of the URDFs shipped by the `example-robot-data` wheel (a cmeel prefix in
    site-packages)."""
    return (Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data"
            / "robots")


def resolve_urdf(text: str) -> Path:
    """Absolute path of a URDF named in a solution file (repository-relative or
    example-robot-data:)."""
    if text.startswith(ERD_PREFIX):
        return example_robot_data_dir() / text[len(ERD_PREFIX):]
    p = Path(text)
    if p.is_absolute():
        return p
    for root in data_roots():
        if (root / p).is_file():
            return root / p
    return REPO_ROOT / p


def resolve_path(rd: Reader, text: Any, key: str, problem_path: Path) -> tuple[Path, str]:
    """Absolute path of a file named in a problem, and its path relative to the repository."""
    text = rd.string(text, key)
    if text.startswith(ERD_PREFIX):
        path = example_robot_data_dir() / text[len(ERD_PREFIX):]
        if not path.is_file():
            raise rd.fail(key, f"'{text}' not found in the example-robot-data package "
                               f"({example_robot_data_dir()})")
        return path, text
    bases = (*data_roots(), problem_path.resolve().parent)
    for base in bases:
        candidate = (base / text).resolve()
        if candidate.is_file():
            return candidate, _relative_name(candidate)
    raise rd.fail(key, f"file '{text}' not found (looked in {', '.join(str(b) for b in bases)})")


def _relative_name(path: Path) -> str:
    """`path` relative to the checkout or the package data (as a solution file records it), else
    absolute."""
    for root in data_roots():
        try:
            return str(path.relative_to(root.resolve()))
        except ValueError:
            pass
    return str(path)

