"""The package as a user gets it: a wheel that installs into a clean venv and runs from there,
and a ``--version`` that says which release it is."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
from pathlib import Path

import pytest

import formula_tourney

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT_VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
BUILT_IN_TRACKS = {"oval", "technical", "flowing"}


def _clean_env() -> dict[str, str]:
    """The caller's environment less the variables that would put this checkout on sys.path."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A venv holding only the wheel built from this checkout; it sees the dependencies through
    a plain path line to this interpreter's site-packages (no network, no index), which appends
    that folder to sys.path without processing its .pth files, so the editable install there
    stays out and ``formula_tourney`` can only come from the wheel."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"  # a copy, so the build's egg-info and build/ folders never touch the checkout
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(
        ROOT / "formula_tourney", src / "formula_tourney",
        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"),
    )  # fmt: skip
    dist = tmp / "dist"
    # `python -m build` (the dev extra's `build`), without an isolated env: nothing downloaded
    subprocess.run(
        [sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(dist),
         str(src)],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    (wheel,) = dist.glob("formula_tourney-*.whl")
    env_dir = tmp / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps",
         "--no-index", "-q", str(wheel)],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True, env=_clean_env(),
    ).stdout.strip()  # fmt: skip
    (Path(site) / "outer_site.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return env_dir


def test_wheel_installs_and_lists_the_built_in_tracks(wheel_venv: Path, tmp_path: Path) -> None:
    run = {"cwd": tmp_path, "env": _clean_env(), "capture_output": True, "text": True}
    where = subprocess.run(
        [str(wheel_venv / "bin" / "python"), "-c",
         "import formula_tourney; print(formula_tourney.__file__)"],
        check=True, **run,
    ).stdout.strip()  # fmt: skip
    assert Path(where).is_relative_to(wheel_venv), where
    listed = subprocess.run(
        [str(wheel_venv / "bin" / "formula-tourney"), "tracks", "list", "--json"], **run
    )
    assert listed.returncode == 0, listed.stderr
    assert {t["name"] for t in json.loads(listed.stdout)["tracks"]} >= BUILT_IN_TRACKS
    shown = subprocess.run([str(wheel_venv / "bin" / "formula-tourney"), "--version"], **run)
    assert shown.returncode == 0
    assert shown.stdout.strip() == f"formula-tourney {PYPROJECT_VERSION}"


def test_version_option_prints_the_package_version_and_exits_0() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "formula_tourney.cli", "--version"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"formula-tourney {formula_tourney.__version__}"
    assert formula_tourney.__version__ != "0+unknown"
