"""The installed distribution: one top-level import name, `codec`, which carries the
command line tool (codec.cli, `python -m codec`, `atm`) and the format's spec and
conformance files (codec.format_spec)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(code: str, cwd: Path) -> subprocess.CompletedProcess:
    # outside the repository, so only what is installed can be imported
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd)


def test_only_codec_is_installed_at_top_level(tmp_path):
    out = _run(
        "import importlib.util as u; "
        "print([n for n in ('codec', 'cli', 'format_spec') if u.find_spec(n)])",
        tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "['codec']"


def test_cli_and_spec_install_inside_codec(tmp_path):
    code = (
        "import importlib.resources as r, codec.cli.main, codec.format_spec.schema as s; "
        "spec = r.files('codec.format_spec'); "
        "print(s.VERSION, spec.joinpath('ATM.md').is_file(), "
        "len([f for f in spec.joinpath('conformance').iterdir() if f.name.endswith('.atm')]))"
    )
    out = _run(code, tmp_path)
    assert out.returncode == 0, out.stderr
    version, has_spec, vectors = out.stdout.split()
    assert has_spec == "True"
    assert int(vectors) == len(list((ROOT / "format_spec" / "conformance").glob("*.atm"))) > 0


def test_python_m_codec_is_the_cli_and_python_m_cli_is_gone(tmp_path):
    ok = subprocess.run([sys.executable, "-m", "codec", "--version"], capture_output=True, text=True, cwd=tmp_path)
    assert ok.returncode == 0 and ok.stdout.startswith("atm "), ok.stderr
    gone = subprocess.run([sys.executable, "-m", "cli", "--version"], capture_output=True, text=True, cwd=tmp_path)
    assert gone.returncode != 0 and "No module named cli" in gone.stderr


def test_pyproject_maps_every_package_under_codec():
    tomllib = pytest.importorskip("tomllib")
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    tools = config["tool"]["setuptools"]
    assert all(p == "codec" or p.startswith("codec.") for p in tools["packages"])
    for package, folder in tools["package-dir"].items():
        assert package.startswith("codec.") and (ROOT / folder / "__init__.py").is_file()
    # every package folder of the runtime is listed (a missing one would not install)
    found = {"codec." + p.parent.relative_to(ROOT / "codec").as_posix().replace("/", ".")
             for p in (ROOT / "codec").rglob("__init__.py") if p.parent != ROOT / "codec"}
    assert found <= set(tools["packages"])
    assert config["project"]["scripts"]["atm"] == "codec.cli.main:main"
    assert (ROOT / "codec" / "py.typed").is_file() and "py.typed" in config["tool"]["setuptools"]["package-data"]["codec"]
