"""Issue 33's invariant: what brl computes is bit-identical to the commit before the redesign (slow: both trees run
a plan of brl commands; `python scripts/check_invariant.py 5a19324` is the full check)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BASE = "5a19324"


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_outputs_are_bit_identical_to_the_commit_before_the_redesign(tmp_path: Path) -> None:
    known = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{BASE}^{{commit}}"], capture_output=True)
    if known.returncode != 0:
        pytest.skip(f"commit {BASE} is not in this checkout (a shallow clone)")
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "check_invariant.py"), BASE, "--quick", "--work",
                        str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "outputs identical" in r.stdout
