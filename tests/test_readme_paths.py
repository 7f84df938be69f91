"""README.md and docs/ against the repository: every file path they name exists, and the
README's one-game table (the paper's footing) equals the committed reproduction data."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: The committed per-instance table of the paper reproduction (one game per OCF plan call).
PER_INSTANCE = ROOT / "reports" / "paper-reproduction" / "tables" / "per_instance.csv"
SCALES = ("4/10", "8/20", "16/40", "32/80")
#: The README block that `paper_reproduction.py write-budgets` writes (benchmarks/).
HEADLINE_BEGIN = "<!-- headline: written by"
HEADLINE_END = "<!-- /headline -->"

CODE = re.compile(r"`([^`\n]+)`")
LINK = re.compile(r"\]\(([^)\s]+)\)")
EXTENSION = re.compile(r"\.[A-Za-z][A-Za-z0-9]{0,7}$")
#: A placeholder word in a path: NAME, MODE, INSTANCE, RUN_DIR, ... (README is a real name).
PLACEHOLDER = re.compile(r"(?<![A-Za-z])(?!README\b)[A-Z][A-Z_]{2,}(?![a-z])")
#: Paths named relative to a run's results or report folder, not to the repository.
RUN_OUTPUTS = ("results/", "reports/latest/", "tables/", "figures/", "solutions/")


def looks_like_path(text: str) -> bool:
    """A repository path as the pages write one: no spaces, a '/', and an extension or a
    trailing '/'; no URL, glob or placeholder (`results/NAME/`, `<dir>`, `*.json`, `.../`)."""
    if any(c.isspace() for c in text) or "/" not in text or "://" in text:
        return False
    if not (text.endswith("/") or EXTENSION.search(text)):
        return False
    if any(c in text for c in "*<>{}[]$~") or "..." in text or PLACEHOLDER.search(text):
        return False
    return not text.startswith(RUN_OUTPUTS)


def named_paths(page: Path) -> list[tuple[str, list[Path]]]:
    """Each path ``page`` names, with the places it may mean: a link is relative to the page,
    a path in backticks to the repository root (or, as a link would be, to the page)."""
    text = page.read_text()
    found = []
    for match in LINK.finditer(text):
        target = match.group(1).split("#")[0]
        local = target and "://" not in target and not target.startswith("mailto:")
        if local and (looks_like_path(target) or EXTENSION.search(target)):
            found.append((target, [page.parent / target]))
    for match in CODE.finditer(text):
        if looks_like_path(match.group(1)):
            found.append((match.group(1), [ROOT / match.group(1), page.parent / match.group(1)]))
    return found


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_path_a_page_names_exists(page: Path) -> None:
    missing = sorted({name for name, places in named_paths(page)
                      if not any(place.exists() for place in places)})
    assert not missing, f"{page.relative_to(ROOT)} names paths that do not exist: {missing}"


def test_path_filter_keeps_paths_and_skips_placeholders() -> None:
    assert looks_like_path("docs/model.md")
    assert looks_like_path("instances/paper/")
    assert looks_like_path("reports/paper-reproduction/README.md")
    for skipped in ("results/NAME/results.sqlite", "tables/pivot-MODE.tex", "*.json",
                    "https://example.org/a.html", "tsac-bench run instances/", "16/40",
                    "reports/latest/index.md", ".../", "DIR/policy.pt", "N/M"):
        assert not looks_like_path(skipped), skipped


def without_headline_block(text: str) -> str:
    if HEADLINE_BEGIN not in text:
        return text
    begin = text.index(HEADLINE_BEGIN)
    end = text.index(HEADLINE_END, begin) + len(HEADLINE_END)
    return text[:begin] + text[end:]


def readme_one_game_table() -> dict[str, list[str]]:
    """The README's table of median (mean) J per method with the scales as its columns,
    outside the generated headline block: method -> cells in the order of SCALES."""
    lines = without_headline_block((ROOT / "README.md").read_text()).splitlines()
    header = "| method | " + " | ".join(SCALES) + " |"
    starts = [i for i, line in enumerate(lines) if line.strip() == header]
    assert len(starts) == 1, f"expected one README table with the header {header!r}"
    rows = {}
    for line in lines[starts[0] + 2:]:
        if not line.startswith("|"):
            break
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def test_readme_one_game_table_equals_the_committed_data() -> None:
    pd = pytest.importorskip("pandas")
    table = pd.read_csv(PER_INSTANCE)
    dynamic = table[(table["mode"] == "dynamic") & table["scale"].isin(SCALES)]
    stats = dynamic.groupby(["method", "scale"])["J"].agg(["median", "mean", "count"])
    expected = {method: [f"{stats.at[(method, s), 'median']:.1f} "
                         f"({stats.at[(method, s), 'mean']:.1f})" for s in SCALES]
                for method in sorted(dynamic["method"].unique())}
    assert readme_one_game_table() == expected
    # The caption says 100 instances per scale.
    assert set(stats["count"]) == {100}


#: An absolute path of the machine a page was written on (the standard: committed reports and
#: docs name paths relative to the project).
MACHINE_PATH = re.compile(r"(?:^|[\s`(\"'=])/(?:tmp|work|root|home|Users|mnt)/")
COMMITTED_TEXT = [p for p in [*PAGES, *sorted((ROOT / "reports").rglob("*"))]
                  if p.suffix in (".md", ".tex", ".csv", ".jsonl")
                  and "latest" not in p.relative_to(ROOT).parts]


@pytest.mark.parametrize("page", COMMITTED_TEXT, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_committed_page_names_a_path_of_the_machine_it_ran_on(page: Path) -> None:
    for number, line in enumerate(page.read_text().splitlines(), 1):
        assert not MACHINE_PATH.search(line), f"{page.name}:{number}: {line[:120]}"


def test_the_machine_path_rule_catches_a_report_command() -> None:
    assert MACHINE_PATH.search("Command: `python x.py --out /tmp/diag/es-new.md`")
    assert not MACHINE_PATH.search("Command: `python x.py --out reports/exact-scaling.md`")
