"""The README opens with exactly two set-up commands, and CI runs the second one verbatim."""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def setup_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    first_block = re.search(r"```(?:bash|sh|console)?\n(.*?)```", text, re.S)
    assert first_block, "README has no code block"
    return [ln.strip() for ln in first_block.group(1).splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def test_readme_starts_with_two_commands():
    text = (ROOT / "README.md").read_text()
    assert text.index("```") < text.index("\n## "), "the set-up commands come before any section"
    commands = setup_commands()
    assert commands == ["pip install . && online-backlash demo", "scripts/test"]
    assert os.access(ROOT / "scripts" / "test", os.X_OK), "scripts/test runs as a command (git keeps its mode 755)"


def test_ci_runs_the_readme_test_command():
    if not (ROOT / ".ci" / "run").exists():
        pytest.fail(".ci/run is missing")
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert setup_commands()[1] in [ln.strip() for ln in ci]


def load_test_command():
    """``scripts/test`` as a module (a script without the .py suffix)."""
    loader = importlib.machinery.SourceFileLoader("scripts_test", str(ROOT / "scripts" / "test"))
    spec = importlib.util.spec_from_loader(loader.name, loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def test_the_test_command_finds_the_missing_debian_packages(tmp_path):
    script = load_test_command()
    assert script.missing_packages(tmp_path, make_venv=False) == list(script.PACKAGES)
    for path in ("usr/lib/postgresql/15/bin/initdb", "usr/sbin/mosquitto", "usr/bin/chromedriver"):
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).touch()
    assert script.missing_packages(tmp_path, make_venv=False) == ["chromium"]
    needs_venv = importlib.util.find_spec("ensurepip") is None  # Debian's python3 without python3-venv
    assert script.missing_packages(tmp_path, make_venv=True) == ["chromium", *(["python3-venv"] if needs_venv else [])]


def test_without_root_the_test_command_prints_the_apt_line_and_stops(capsys, monkeypatch):
    script = load_test_command()
    monkeypatch.setattr(script.subprocess, "run", lambda *a, **k: pytest.fail(f"ran {a}"))  # installs nothing
    assert script.provide(["mosquitto", "chromium"], as_root=False) is False
    assert capsys.readouterr().err == (
        "error: the tests need Debian packages that are not installed: mosquitto chromium\n"
        "as root, run: apt-get install -y mosquitto chromium\n"
    )
    assert script.provide([], as_root=False) is True


def test_readme_python_example_runs():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, "README has no Python example"
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)
    assert abs(namespace["rls"].backlash_ - 0.5) < 0.01
    assert abs(namespace["est"].backlash_ - 1.2) < 1e-6


def test_readme_python_commands_import_from_the_project_root():
    """From the root, where a user has just run ``pip install .``, the README's ``python -c`` lines import the
    installed package: no source folder named ``online_backlash`` shadows it without ``drivers``/``replay``."""
    import subprocess
    import sys

    text = (ROOT / "README.md").read_text()
    imports = sorted(set(re.findall(r'python -c "(from online_backlash[.\w]* import \w+)', text)))
    assert imports, "README has no python -c example"
    proc = subprocess.run([sys.executable, "-c", "; ".join(imports)], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
