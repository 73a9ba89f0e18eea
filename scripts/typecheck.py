"""mypy on the package as it installs.

``drivers/`` and ``replay/`` are mapped into ``online_backlash`` by ``[tool.setuptools] package-dir``
in ``pyproject.toml``, which mypy cannot follow in the source tree. This script stages the package
the way the mapping lays it out (a copy in a temporary folder), runs mypy there with the
project's ``[tool.mypy]`` settings, and maps the paths in mypy's report back to the source tree.
Exit status: mypy's.

    python scripts/typecheck.py
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def package_dirs() -> dict[str, Path]:
    """Package name -> source folder, as pyproject.toml maps them (longest names last)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    mapping = config["tool"]["setuptools"]["package-dir"]
    return {name: ROOT / folder for name, folder in sorted(mapping.items(), key=lambda kv: kv[0].count("."))}


def main() -> int:
    dirs = package_dirs()
    with tempfile.TemporaryDirectory(prefix="online-backlash-typecheck.") as stage:
        for name, folder in dirs.items():
            shutil.copytree(
                folder, Path(stage, *name.split(".")), dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__")
            )
        proc = subprocess.run(
            [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"), "-p", "online_backlash"],
            cwd=stage,
            capture_output=True,
            text=True,
        )
    report = proc.stdout + proc.stderr
    for name, folder in sorted(dirs.items(), key=lambda kv: -kv[0].count(".")):  # deepest mapping first
        staged = name.replace(".", "/") + "/"
        report = "\n".join(
            str(folder.relative_to(ROOT)) + "/" + line[len(staged) :] if line.startswith(staged) else line
            for line in report.splitlines()
        )
    print(report)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
