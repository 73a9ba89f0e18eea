"""``keep_freed_memory``: freed blocks reused, not page-faulted in anew; set by ``estimate`` and ``diagnose``.

Each check runs in a fresh interpreter: the setting is the whole process's.
"""

from __future__ import annotations

import platform
import subprocess
import sys
import textwrap

import pytest

from online_backlash.simulation.rig import simulate_rig

glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")

#: minor page faults of touching a 64 MiB block again after freeing it: about 16,000 (4 KiB pages)
#: when glibc unmaps it on free, a handful when the heap keeps it
REFAULT = """
import resource
def faults_of_a_second_block():
    block = bytearray(64 << 20)  # zero-filled: every page touched
    del block
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = bytearray(64 << 20)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
"""


def _python(code: str) -> str:
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@glibc
def test_a_freed_block_is_reused_without_page_faults():
    out = _python(
        REFAULT
        + """
from online_backlash._allocator import keep_freed_memory
print(keep_freed_memory(), faults_of_a_second_block())
"""
    )
    applied, faults = out.split()
    assert applied == "True"
    assert int(faults) < 1000  # 64 MiB in 4 KiB pages would be 16,384


def test_numpy_stops_advising_huge_pages():
    out = _python(
        """
import numpy as np
from online_backlash._allocator import keep_freed_memory
keep_freed_memory()
print(np._core.multiarray._set_madvise_hugepage(True))  # returns the setting it replaces
"""
    )
    assert out == "False"


@pytest.mark.parametrize("command", [["estimate", "--method", "batch"], ["diagnose", "--max-terms", "0"]])
def test_the_record_commands_set_it(tmp_path, command):
    path = tmp_path / "rig.csv"
    simulate_rig(duration_s=5.0, ratio=30.0, play_deg=0.5, seed=3).write_csv(path)
    out = _python(
        f"""
import contextlib, io
import numpy as np
from online_backlash.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    assert main([{command[0]!r}, {str(path)!r}, "--ratio", "30", "--json", *{command[1:]!r}]) == 0
print(np._core.multiarray._set_madvise_hugepage(True))
"""
    )
    assert out == "False"
