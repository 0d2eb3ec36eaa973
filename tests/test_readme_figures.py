"""The result tables of the README and of the docs pages agree with the committed JSONs behind them
(benchmarks.readme_figures, in process: no benchmark runs), their markers are well formed, a figure edited by
hand is reported, and every relative link of the README and docs/ points to a file (and heading) that exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from benchmarks import figure_text as ft
from benchmarks import readme_figures as rf

DOCS_DIR = rf.ROOT / "docs"
PAGES = (rf.ROOT / "README.md", *sorted(DOCS_DIR.rglob("*.md")))  # what a reader follows links through


def test_every_block_and_model_card_agrees_with_its_json():
    bad = rf.check()
    assert not bad, "re-render with `python -m benchmarks.readme_figures`: " + "; ".join(bad)


@pytest.mark.parametrize("doc", rf.DOCS, ids=lambda p: str(p.relative_to(rf.ROOT)))
def test_each_marker_pair_is_well_formed(doc):
    text = doc.read_text()
    found = rf.blocks(text)  # raises on an unpaired, nested, repeated or unknown marker
    assert len(found) == text.count("<!-- figures:") == text.count("<!-- /figures:")
    for name, start, end in found:
        assert text[start:end].startswith("\n") and text[start:end].endswith("\n"), name


def test_every_render_function_has_one_block():
    names = [name for doc in rf.DOCS for name, _, _ in rf.blocks(doc.read_text())]
    assert sorted(names) == sorted(rf.BLOCKS)


@pytest.mark.parametrize("text, message", [
    ("<!-- figures:act -->\n", "never closed"),
    ("<!-- /figures:act -->\n", "closes nothing"),
    ("<!-- figures:act -->\n<!-- figures:pose -->\n<!-- /figures:pose -->\n<!-- /figures:act -->\n", "inside"),
    ("<!-- figures:act -->\n<!-- /figures:pose -->\n", "closes figures:act"),
    ("<!-- figures:act -->\n<!-- /figures:act -->\n" * 2, "twice"),
    ("<!-- figures:nonesuch -->\n<!-- /figures:nonesuch -->\n", "no render function"),
])
def test_a_malformed_marker_is_refused(text, message):
    with pytest.raises(ValueError, match=message):
        rf.blocks(text)


def _page_with(name: str) -> Path:
    return next(doc for doc in rf.DOCS if name in [b[0] for b in rf.blocks(doc.read_text())])


def test_the_readme_and_every_docs_page_are_rendered():
    assert rf.ROOT / "README.md" in rf.DOCS
    assert set(DOCS_DIR.glob("*.md")) <= set(rf.DOCS)
    assert _page_with("headline") == rf.ROOT / "README.md"  # the front door's one table of headline figures


def test_a_figure_edited_by_hand_is_caught():
    doc = _page_with("act")
    text = doc.read_text()
    _, start, end = next(b for b in rf.blocks(text) if b[0] == "act")
    body = text[start:end]
    figure = re.search(r"\d+ % \[\d+, \d+\]", body).group()  # the block's first success rate
    edited = text[:start] + body.replace(figure, "1" + figure, 1) + text[end:]
    fixed, changed = rf.rendered(edited)
    assert changed == ["act"] and fixed == text


@pytest.mark.parametrize("doc", rf.DOCS, ids=lambda p: str(p.relative_to(rf.ROOT)))
def test_any_figure_edited_by_hand_in_any_block_is_caught(doc):
    text = doc.read_text()
    for name, start, end in rf.blocks(text):
        body = text[start:end]
        digit = re.search(r"\d", body)
        assert digit, f"figures:{name} holds no figure"
        i = start + digit.start()
        edited = text[:i] + str((int(text[i]) + 1) % 10) + text[i + 1:]
        assert rf.rendered(edited)[1] == [name], name


def test_check_names_the_page_and_the_block(tmp_path, monkeypatch):
    doc = _page_with("headline")
    text = doc.read_text()
    _, start, end = next(b for b in rf.blocks(text) if b[0] == "headline")
    body = text[start:end]
    assert "no detectable effect" in body
    page = tmp_path / "README.md"
    page.write_text(text[:start] + body.replace("no detectable effect", "helps", 1) + text[end:])
    monkeypatch.setattr(rf, "DOCS", (page,))
    assert [b for b in rf.check() if "figures:" in b] == [f"{page}: figures:headline"]
    assert rf.main(["--check"]) == 1
    page.write_text(text)
    assert rf.main(["--check"]) == 0


# -- links ----------------------------------------------------------------------------------------------------

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _prose(text: str):
    """The lines outside fenced code blocks, inline code removed (``[0, 1](x)`` in code is no link)."""
    fenced = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced:
            yield re.sub(r"`[^`]*`", "", line)


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation and symbols dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    fenced = False
    for line in page.read_text().splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and (m := re.match(r"#{1,6}\s+(.*)", line)):
            slug = _slug(m.group(1).replace("`", ""))
            seen[slug] = seen.get(slug, 0) + 1
            yield slug if seen[slug] == 1 else f"{slug}-{seen[slug] - 1}"


def broken_links(page: Path) -> list[str]:
    bad = []
    for line in _prose(page.read_text()):
        for target in LINK.findall(line):
            if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
                continue
            file, _, anchor = target.partition("#")
            dest = (page.parent / file).resolve() if file else page
            if not dest.exists():
                bad.append(f"{target}: no such file")
            elif anchor and dest.suffix == ".md" and anchor not in set(anchors(dest)):
                bad.append(f"{target}: no heading #{anchor} in {dest.name}")
    return bad


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(rf.ROOT)))
def test_every_relative_link_points_to_an_existing_file(page):
    assert not broken_links(page), broken_links(page)


def test_a_broken_link_is_reported(tmp_path):
    (tmp_path / "there.md").write_text("# A heading: here\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](there.md#a-heading-here) [gone](missing.md) ![img](nope.png) [bad](there.md#elsewhere)\n"
                    "`[code](not_a_link.md)`\n```\n[fenced](not_a_link.md)\n```\n[web](https://example.com/x)\n")
    assert broken_links(page) == ["missing.md: no such file", "nope.png: no such file",
                                  "there.md#elsewhere: no heading #elsewhere in there.md"]


def test_the_front_picture_is_small_and_made_by_its_script():
    picture = DOCS_DIR / "front.png"
    assert picture.stat().st_size < 300_000
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "docs/front.png" in (rf.ROOT / "README.md").read_text()
    assert "generate_images" in (DOCS_DIR / "make_front_picture.py").read_text()


def test_the_readme_keeps_ci_s_test_command_and_stays_short():
    text = (rf.ROOT / "README.md").read_text()
    commands = text.split("```bash\n", 1)[1].split("```", 1)[0]  # the README's first command block
    assert any(line.split("#")[0].split() == ["./run.sh", "test"] for line in commands.splitlines())
    assert "./run.sh test" in (rf.ROOT / ".ci" / "run").read_text()
    assert len(text.splitlines()) <= 250


def test_history_is_marked_for_a_dirty_tree_or_an_earlier_generator():
    doc = {"machine": {"git_commit": "abc1234", "date_utc": "2026-01-01T00:00:00+00:00"}}
    assert ft.provenance("x.json", doc, ft.SHIPPED_GENERATOR).startswith("*Source:")
    assert "History" in ft.provenance("x.json", doc, "e87cbc3c3742019b")
    dirty = {"machine": {"git_commit": "abc1234-dirty", "date_utc": "2026-01-01T00:00:00+00:00"}}
    assert "dirty tree" in ft.provenance("x.json", dirty, ft.SHIPPED_GENERATOR)


def test_every_source_line_names_the_machine_its_figures_were_measured_on():
    stamp = {"git_commit": "abc1234", "date_utc": "2026-01-01T00:00:00+00:00"}
    cpu = {"machine": {**stamp, "cpu": "AMD  EPYC", "cores": 2, "cuda_device": None}}
    gpu = {"machine": {**stamp, "cpu": "Intel Xeon", "cores": 16, "cuda_device": "NVIDIA H200"}}
    assert ", on AMD EPYC (2 cores)." in ft.provenance("x.json", cpu, None)
    assert ", on Intel Xeon (16 cores), with NVIDIA H200." in ft.provenance("x.json", gpu, None)
    assert ft.provenance("x.json", {"machine": stamp}, None) == "*Source: `benchmarks/results/x.json`, commit abc1234, 2026-01-01.*"


def test_the_shipped_generator_hash_is_the_default_checkpoints():
    from controltac_il.generator.checkpoint import checkpoint_hash

    assert checkpoint_hash(ft.ROOT / "controltac_il/generator/checkpoints/default") == ft.SHIPPED_GENERATOR


def test_a_timed_median_is_quoted_with_its_interquartile_range_or_as_one_timing():
    from benchmarks.docs_figures import timing_spread

    assert timing_spread({"ms_quartiles": [8.51, 9.46], "calls": 30}, "call", "calls") == \
        "8.5–9.5 ms per call (interquartile, 30 calls)"
    assert timing_spread({"ms_per_chunk": 9.0}, "call", "calls") == "one timing, no interval"
