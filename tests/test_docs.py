"""The documentation's promises: a one-page README that links every page, local links that resolve, and a
configuration reference that is the schema's current output with every key described."""

import re
from pathlib import Path

from cafe_mpc.config.reference import generated_block, reference_markdown, undocumented_keys

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
BENCHMARKS = ROOT / "BENCHMARKS.md"
HISTORY = ROOT / "benchmarks" / "history"
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _local_links(page: Path) -> list[str]:
    return [
        target.split("#")[0]
        for target in LINK.findall(page.read_text())
        if not target.startswith(("http://", "https://", "mailto:", "#"))
    ]


def test_readme_is_one_page_and_links_every_doc():
    assert README.stat().st_size <= 12 * 1024, f"README.md is {README.stat().st_size} bytes (limit 12 KB)"
    linked = {Path(target).as_posix() for target in _local_links(README)}
    missing = [f"docs/{page.name}" for page in sorted(DOCS.glob("*.md")) if f"docs/{page.name}" not in linked]
    assert not missing, f"README.md does not link {missing}"
    assert "BENCHMARKS.md" in linked


def test_local_links_resolve():
    broken = []
    for page in [README, BENCHMARKS, *sorted(DOCS.glob("*.md")), *sorted(HISTORY.glob("*.md"))]:
        for target in _local_links(page):
            if target and not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, broken


def test_benchmarks_is_one_page_of_current_numbers_and_links_its_history():
    assert BENCHMARKS.stat().st_size <= 40 * 1024, (
        f"BENCHMARKS.md is {BENCHMARKS.stat().st_size} bytes (limit 40 KB)"
    )
    assert "benchmarks/history/README.md" in _local_links(BENCHMARKS)
    indexed = set(_local_links(HISTORY / "README.md"))
    unlisted = [
        page.name
        for page in sorted(HISTORY.glob("*.md"))
        if page.name != "README.md" and page.name not in indexed
    ]
    assert not unlisted, f"benchmarks/history/README.md does not list {unlisted}"


def test_every_config_key_is_documented():
    assert undocumented_keys() == [], "give these schema fields a description (Field(..., description=...))"


def test_configuration_reference_is_current():
    block = generated_block((DOCS / "configuration.md").read_text())
    assert block is not None, "docs/configuration.md lost its generated block"
    assert block == reference_markdown(), (
        "docs/configuration.md is out of date: regenerate it with "
        "cafe-mpc config --update docs/configuration.md"
    )
