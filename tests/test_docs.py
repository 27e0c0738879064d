"""The docs the code and the README point to exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_doc_path_the_code_cites_exists() -> None:
    cited: set[str] = set()
    for folder in ("brlcli", "tests", "scripts", "benchmarks"):
        for f in (ROOT / folder).rglob("*.py"):
            cited |= set(re.findall(r"\bdocs/[A-Za-z0-9_./-]*[A-Za-z0-9_-]", f.read_text(encoding="utf-8")))
    assert "docs/method.md" in cited
    missing = sorted(p for p in cited if not (ROOT / p).exists())
    assert not missing, missing


def test_every_relative_link_of_the_readme_and_docs_exists() -> None:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), ROOT / "models" / "README.md"]
    broken = []
    for page in pages:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not broken, broken
