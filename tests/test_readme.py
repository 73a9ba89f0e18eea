"""The README opens with exactly two set-up commands, and CI runs the second one verbatim."""

from __future__ import annotations

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
    assert len(commands) == 2
    assert "online-backlash demo" in commands[0] and "pip install" in commands[0]
    assert "pytest" in commands[1] and ".[test]" in commands[1]


def test_ci_runs_the_readme_test_command():
    if not (ROOT / ".ci" / "run").exists():
        pytest.fail(".ci/run is missing")
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert setup_commands()[1] in [ln.strip() for ln in ci]


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
