"""The type stubs (dpr_gpu/*.pyi) describe the compiled module as it is: mypy's stubtest compares them with
the runtime signatures, names and classes. CI installs mypy; elsewhere the test is skipped without it."""

from __future__ import annotations

import subprocess
import sys

import pytest


def test_stubs_match_the_compiled_module():
    pytest.importorskip("mypy", reason="pip install mypy to check the stubs")
    done = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "dpr_gpu"], capture_output=True, text=True, check=False, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr
