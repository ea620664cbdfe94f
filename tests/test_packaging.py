"""The installable package: shipped data found from any folder, the wheel's contents, `--version`,
LICENSE.

The wheel test builds a wheel from a clean clone of the committed repository, installs it (without
dependencies) into a fresh venv that borrows the dependencies already installed in this
interpreter's site-packages, and solves a problem file copied to another folder.
`make package-check` does the same with the dependencies installed from the package index (slower,
not part of `make test`).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

from surestep_ocp.errors import ProblemError
from surestep_ocp.problem import paths
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.paths import find_shipped

REPO = Path(__file__).resolve().parents[1]


def test_problem_copied_elsewhere_finds_the_shipped_urdf(tmp_path, monkeypatch):
    """An installed layout (no checkout, data under the package): a copied problem resolves
    robots/psm.urdf."""
    fake_site = tmp_path / "site"
    shutil.copytree(REPO / "robots", fake_site / "surestep_ocp" / "data" / "robots")
    # site-packages: no pyproject.toml, no robots/
    monkeypatch.setattr(paths, "REPO_ROOT", fake_site)
    monkeypatch.setattr(paths, "PACKAGE_DATA", fake_site / "surestep_ocp" / "data")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.copy(REPO / "problems" / "needle_regrasp.yaml", elsewhere / "mine.yaml")
    monkeypatch.chdir(tmp_path)
    p = load_problem(elsewhere / "mine.yaml")
    assert p.robot.urdf == (fake_site / "surestep_ocp" / "data" / "robots" / "psm.urdf").resolve()
    assert p.robot.urdf_rel == "robots/psm.urdf"
    assert (paths.resolve_urdf(p.robot.urdf_rel)
            == fake_site / "surestep_ocp" / "data" / "robots" / "psm.urdf")


def test_missing_urdf_names_every_folder_looked_in(tmp_path, monkeypatch):
    monkeypatch.setattr(paths, "REPO_ROOT", tmp_path / "nowhere")
    monkeypatch.setattr(paths, "PACKAGE_DATA", tmp_path / "nodata")
    shutil.copy(REPO / "problems" / "needle_regrasp.yaml", tmp_path / "p.yaml")
    with pytest.raises(ProblemError) as exc:
        load_problem(tmp_path / "p.yaml")
    msg = str(exc.value)
    assert ("robot.urdf" in msg and "robots/psm.urdf" in msg and str(tmp_path) in msg
            and "\n" not in msg)


def test_shipped_problem_found_by_its_relative_name_from_another_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert not (tmp_path / "problems").exists()
    path = find_shipped("problems/needle_regrasp.yaml")
    assert path.resolve() == (REPO / "problems" / "needle_regrasp.yaml").resolve()
    assert load_problem("problems/needle_regrasp.yaml").name == "needle_regrasp"
    # left for the caller to report
    assert find_shipped("problems/no_such.yaml") == Path("problems/no_such.yaml")


def test_package_data_patterns_cover_every_data_file():
    """Each file in robots/ and problems/ is matched by a package-data pattern of its mapped
    package."""
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = {pkg: REPO / d for pkg, d in cfg["package-dir"].items()
            if pkg.startswith("surestep_ocp.data")}
    assert {d.relative_to(REPO).as_posix() for d in dirs.values()} >= {"robots", "problems",
                                                                       "problems/evaluations"}
    for pkg, d in dirs.items():
        assert pkg in cfg["packages"]
        tracked = subprocess.run(["git", "ls-files", d.relative_to(REPO).as_posix()], cwd=REPO,
                                 capture_output=True, text=True).stdout.split()
        files = ([REPO / f for f in tracked if (REPO / f).parent == d]
                 or [f for f in d.iterdir() if f.is_file()])
        for f in files:
            assert any(f.match(pat) for pat in cfg["package-data"][pkg]), (f"{f} is not "
                                                                           f"shipped ({pkg})")


def test_license_and_version():
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("MIT License") and "WITHOUT WARRANTY" in text
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert meta["license"] == "MIT"  # SPDX expression (the table form is deprecated)
    out = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "--version"],
                         capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"surestep {meta['version']}"


def test_validate_every_problem_file_passes():
    """The README's first usage line: `surestep validate problems/*.yaml` exits 0."""
    files = sorted(str(p.relative_to(REPO)) for p in (REPO / "problems").glob("*.yaml"))
    out = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "validate", *files], cwd=REPO,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("ok ") == len(files)


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(),
                    reason="needs a git checkout")
def test_wheel_from_clean_clone_solves_a_copied_problem(tmp_path):
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{REPO}", str(clone)], check=True)
    wheels = tmp_path / "wheels"
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                            str(wheels), str(clone)],
                           capture_output=True, text=True)
    if build.returncode != 0 and "Could not find a version that satisfies" in build.stderr:
        pytest.skip("no package index to fetch the build backend from")
    assert build.returncode == 0, build.stderr[-2000:]
    (wheel,) = wheels.glob("surestep_ocp-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for f in ("surestep_ocp/data/robots/psm.urdf", "surestep_ocp/data/robots/ecm.urdf",
              "surestep_ocp/data/problems/needle_regrasp.yaml",
              "surestep_ocp/data/problems/evaluations/evaluation.yaml"):
        assert f in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    vpy = venv / "bin" / "python"
    site = Path(subprocess.run([str(vpy), "-c",
                                "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    # the dependencies already installed here, appended after the venv's own site-packages
    (site / "borrowed_deps.pth").write_text(
        f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(vpy), "install", "-q", "--no-deps",
                    "--no-index", str(wheel)], check=True)
    where = tmp_path / "elsewhere"
    where.mkdir()
    # a problem file copied elsewhere: its URDF is found in the installed package
    shutil.copy(REPO / "problems" / "needle_regrasp_paper_pace.yaml", where / "copied.yaml")
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    located = subprocess.run([str(vpy), "-c", "import surestep_ocp; print(surestep_ocp.__file__)"],
                             cwd=where, env=env, capture_output=True, text=True, check=True).stdout
    assert located.startswith(str(site)), located  # the wheel's copy, not this checkout
    cli = venv / "bin" / "surestep"
    out = subprocess.run([str(cli), "solve", "copied.yaml", "--method", "baseline", "--output",
                          "sol.json"], cwd=where,
                         env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert ((where / "sol.json").is_file()
            and '"urdf": "robots/psm.urdf"' in (where / "sol.json").read_text())
    shipped = subprocess.run([str(cli), "validate", "problems/needle_regrasp.yaml"], cwd=where,
                             env=env, capture_output=True, text=True)
    assert shipped.returncode == 0, shipped.stderr
    version = subprocess.run([str(cli), "--version"], env=env, capture_output=True, text=True)
    assert version.stdout.startswith("surestep ")
