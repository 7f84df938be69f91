"""Pages written from data (settings tables, the best-known page): write what changed, or
with ``check`` change nothing and report what differs, so a test or CI can hold a page to
its source."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path


def sync(pages: Iterable[tuple[Path, str]], check: bool, source: str) -> int:
    """Write each page whose text differs (none with ``check``); print which, and return the
    exit status: 1 where ``check`` found a page that differs from ``source``."""
    stale = []
    for path, text in pages:
        if not path.exists() or path.read_text() != text:
            stale.append(path.name)
            if not check:
                path.write_text(text)
    verb = f"differ from {source}" if check else "rewritten"
    print(f"{verb}: {', '.join(stale)}" if stale else f"every page matches {source}")
    return 1 if stale and check else 0
