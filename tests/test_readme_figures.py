"""The README's result tables agree with the committed JSONs behind them (benchmarks.readme_figures, in process:
no benchmark runs), and their markers are well formed."""

from __future__ import annotations

import pytest

from benchmarks import readme_figures as rf


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


def test_a_figure_edited_by_hand_is_caught():
    text = rf.DOCS[0].read_text()
    _, start, end = next(b for b in rf.blocks(text) if b[0] == "act")
    body = text[start:end]
    assert "94 % [84, 98]" in body
    edited = text[:start] + body.replace("94 % [84, 98]", "96 % [84, 98]", 1) + text[end:]
    fixed, changed = rf.rendered(edited)
    assert changed == ["act"] and fixed == text


def test_history_is_marked_for_a_dirty_tree_or_an_earlier_generator():
    doc = {"machine": {"git_commit": "abc1234", "date_utc": "2026-01-01T00:00:00+00:00"}}
    assert rf.provenance("x.json", doc, rf.SHIPPED_GENERATOR).startswith("*Source:")
    assert "History" in rf.provenance("x.json", doc, "e87cbc3c3742019b")
    dirty = {"machine": {"git_commit": "abc1234-dirty", "date_utc": "2026-01-01T00:00:00+00:00"}}
    assert "dirty tree" in rf.provenance("x.json", dirty, rf.SHIPPED_GENERATOR)


def test_the_shipped_generator_hash_is_the_default_checkpoints():
    from controltac_il.generator.checkpoint import checkpoint_hash

    assert checkpoint_hash(rf.ROOT / "controltac_il/generator/checkpoints/default") == rf.SHIPPED_GENERATOR
