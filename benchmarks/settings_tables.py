"""The settings tables of docs/, written from each method's declared settings
(``settings_table``: what ``tsac-bench methods NAME`` prints), so that a page cannot state a
default or a range the code does not have.

    python benchmarks/settings_tables.py            # rewrite every table between its markers
    python benchmarks/settings_tables.py --check    # exit 1 where a table differs from the code

A table sits between ``<!-- settings: METHOD -->`` and ``<!-- /settings -->`` in a page of
docs/. The setting, default and allowed columns come from the code; a fourth column,
"meaning", is the page's own and is kept, setting by setting, as written (empty for a setting
the page has not described yet). A table written without that column stays without it.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from generated_pages import sync

from tsac_bench.planning import allocator_class
from tsac_bench.planning.settings import settings_table

DOCS = Path(__file__).resolve().parents[1] / "docs"
BLOCK = re.compile(r"(?P<open><!-- settings: (?P<method>[\w-]+) -->\n)(?P<body>.*?)"
                   r"(?P<close><!-- /settings -->)", re.S)
HEADER = ("setting", "default", "allowed")
MEANING = "meaning"


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def page_meanings(body: str) -> dict[str, str] | None:
    """The meaning the page gives each setting of a table, or None where the table has no
    meaning column."""
    rows = [_cells(line) for line in body.splitlines() if line.startswith("|")]
    if not rows or MEANING not in rows[0]:
        return None
    at = rows[0].index(MEANING)
    return {row[0].strip("`"): row[at] for row in rows[2:] if len(row) > at}


def table(method: str, meanings: dict[str, str] | None) -> str:
    """A method's settings as a Markdown table, with the page's meanings if it has them."""
    columns = [*HEADER, *([MEANING] if meanings is not None else [])]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for name, default, allowed in settings_table(allocator_class(method)):
        cells = [f"`{name}`", default, allowed]
        if meanings is not None:
            cells.append(meanings.get(name, ""))
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    return "\n".join(lines) + "\n"


def rewrite(text: str) -> str:
    """``text`` with every settings table written from the code."""
    def block(match: re.Match) -> str:
        body = table(match["method"], page_meanings(match["body"]))
        return match["open"] + body + match["close"]

    return BLOCK.sub(block, text)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 if a table differs from the code")
    args = parser.parse_args(argv)
    pages = sorted(DOCS.glob("*.md"))
    return sync(((page, rewrite(page.read_text())) for page in pages), args.check, "the code")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
