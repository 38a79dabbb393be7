"""dacrt.compiling: the first compile of an engine kernel in process says so, once, naming
dacrt.warmup() and the cache; a warm-up's compiles are counted, not announced. Each case runs in a
fresh process over an empty cache folder, so that a small kernel really compiles."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

SETUP = """
import sys
import numpy as np
import dacrt.cache
from dacrt import compiling
from dacrt.results import unit_normals

dacrt.cache.use_cache_dir(sys.argv[1])
compiling.watch()
corners = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float32)

def normals(dtype):  # each dtype is a new signature: a compile
    unit_normals(corners.astype(dtype), np.empty((1, 3), dtype))
"""

CASES = {
    "first compile": "normals(np.float32); normals(np.float64)",
    "after a warm-up": "with compiling.warming_up(): normals(np.float32)\nnormals(np.float64)",
    "inside a warm-up": "with compiling.warming_up(): normals(np.float32); normals(np.float64)",
}


def run(case: str, cache: Path) -> subprocess.CompletedProcess:
    code = SETUP + CASES[case] + "\nprint(compiling.compiled_kernels())"
    return subprocess.run(
        [sys.executable, "-c", code, str(cache)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.parametrize("case", list(CASES))
def test_the_first_compile_outside_a_warm_up_says_so_once(case, tmp_path):
    done = run(case, tmp_path / "cache")
    assert done.returncode == 0, done.stderr[-2000:]
    assert int(done.stdout) >= 2  # two signatures compiled, each counted
    lines = done.stderr.splitlines()
    if case == "inside a warm-up":
        assert lines == []
        return
    assert len(lines) == 1, lines
    assert str(tmp_path / "cache") in lines[0]  # where the kernels are kept
    if case == "first compile":
        assert "dacrt.warmup()" in lines[0] and "minutes" in lines[0]
    else:
        assert "did not cover" in lines[0] and "dacrt.results.unit_normals" in lines[0]
