"""The package's source says what the code does and why, not how it got there: no development rounds or issue
numbers in its comments, docstrings or strings (the measurements behind a choice live in docs/research-log.md)."""
from __future__ import annotations

import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "insertnerf_cli"
HISTORY = re.compile(r"round \d+|issue \d+", re.IGNORECASE)


def test_no_development_history_in_the_package():
    hits = [f"{path.relative_to(PACKAGE.parent)}:{number}: {line.strip()}"
            for path in sorted(PACKAGE.rglob("*.py"))
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if HISTORY.search(line)]
    assert not hits, "development history in the package (cite docs/research-log.md instead):\n" + "\n".join(hits)
