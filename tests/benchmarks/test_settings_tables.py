"""The settings tables of docs/ (benchmarks/settings_tables.py) against the code: each equals
what ``settings_table`` gives, and docs/methods.md has a section, with its table, for every
built-in method."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import settings_tables

from tsac_bench.planning import allocator_class, available_methods, method_source
from tsac_bench.planning.settings import settings_table

METHODS_PAGE = settings_tables.DOCS / "methods.md"


def built_in() -> list[str]:
    return [m for m in available_methods() if method_source(m) == "built-in"]


def test_every_table_in_docs_is_the_codes() -> None:
    stale = [page.name for page in sorted(settings_tables.DOCS.glob("*.md"))
             if settings_tables.rewrite(page.read_text()) != page.read_text()]
    assert not stale, f"run `python benchmarks/settings_tables.py`: {stale} differ from the code"


def test_methods_page_has_a_section_and_a_table_for_every_built_in_method() -> None:
    text = METHODS_PAGE.read_text()
    headings = " ".join(re.findall(r"^#{2,3} (.*)$", text, re.M)).lower()
    tables = {match["method"] for match in settings_tables.BLOCK.finditer(text)}
    for method in built_in():
        assert re.search(rf"(?<![\w-]){re.escape(method)}(?![\w-])", headings), method
        if settings_table(allocator_class(method)):
            assert method in tables, method


def test_a_rewrite_takes_defaults_from_the_code_and_keeps_the_pages_meanings() -> None:
    page = ("before\n<!-- settings: cnp -->\n| setting | default | allowed | meaning |\n"
            "|---|---|---|---|\n| `commitment` | deadline | anything | what an award binds |\n"
            "| `gone` | 1 | - | a setting the code no longer has |\n<!-- /settings -->\nafter\n")
    (name, default, allowed), = settings_table(allocator_class("cnp"))
    assert settings_tables.rewrite(page) == (
        "before\n<!-- settings: cnp -->\n| setting | default | allowed | meaning |\n"
        f"|---|---|---|---|\n| `{name}` | {default} | {allowed} | what an award binds |\n"
        "<!-- /settings -->\nafter\n")
    # Without a meaning column the table stays without one.
    plain = page.replace(" meaning |", "").replace("|---|---|---|---|", "|---|---|---|")
    assert "meaning" not in settings_tables.rewrite(plain)
