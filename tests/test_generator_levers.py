"""benchmarks.generator_levers: each variant's command is default's own recipe with its lever, nothing else."""

import json

from benchmarks.generator_levers import VARIANTS, command, recipe, with_values


def test_the_recipe_keeps_the_cards_flags_but_those_each_run_sets():
    card = {"command": "python -m controltac_il.generator.train --data d --out o --stage denoiser --autoencoder-from a "
                       "--denoiser-from a --dit-preset tiny --dit-steps 6000 --dit-lr 0.0003 --distinct-pairs "
                       "--val-objects 10 --seed 5"}
    assert recipe(card) == ["--stage", "denoiser", "--dit-preset", "tiny", "--distinct-pairs", "--val-objects", "10",
                            "--seed", "5"]
    assert with_values(recipe(card), {"--val-objects": "1", "--seed": "2"})[-4:] == ["--val-objects", "1", "--seed", "2"]


def test_a_variant_fine_tunes_default_with_only_its_lever_added(tmp_path):
    from types import SimpleNamespace

    args = SimpleNamespace(data=tmp_path / "d", runs=tmp_path / "r", steps=2000, lr=1e-4, device="cpu", threads=2)
    control, both = (command(args, v, ["--seed", "5"]) for v in ("control", "both"))
    assert control[control.index("--denoiser-from") + 1] == "default" and control[-2:] == ["--seed", "5"]
    out = control.index("--out") + 1
    assert both[out] == str(tmp_path / "r" / "both") and control[out] == str(tmp_path / "r" / "control")
    assert both[:-len(VARIANTS["both"])] == control[:out] + [both[out]] + control[out + 1:]


def _args(tmp_path, steps=2000):
    from types import SimpleNamespace

    return SimpleNamespace(data=tmp_path / "d", runs=tmp_path / "r", steps=steps, lr=1e-4, device="cpu", threads=2)


def _finished(tmp_path, cmd_words):
    """A variant's folder as a finished run leaves it: the final card and the command stamp."""
    final = tmp_path / "r" / "control" / "final"
    final.mkdir(parents=True)
    card = {"denoiser": {"steps": 2000, "wall_s": 812.5, "validation": {"objects": ["procedural_0020"], "best": 0.3}}}
    (final / "model_card.json").write_text(json.dumps(card))
    (tmp_path / "r" / "control" / "levers_command.json").write_text(json.dumps(cmd_words))


def test_a_finished_variant_is_reused_only_for_the_same_command(tmp_path):
    import pytest

    from benchmarks.generator_levers import train

    _finished(tmp_path, command(_args(tmp_path, steps=2), "control", [])[2:])  # a smoke run's folder
    with pytest.raises(SystemExit, match="holds a run of another command"):
        train(_args(tmp_path), "control", [])
    (tmp_path / "r" / "control" / "levers_command.json").write_text(
        json.dumps(command(_args(tmp_path), "control", [])[2:]))
    row = train(_args(tmp_path), "control", [])
    assert row["trained_here"] is False and row["wall_s"] == 812.5 and row["steps"] == 2000


def test_validation_objects_must_be_defaults_and_never_test_objects():
    import pytest

    from benchmarks.generator_levers import validation_objects
    from controltac_il.tactile import HELDOUT_OBJECTS

    card = {"denoiser": {"validation": {"objects": ["procedural_0020", "procedural_0024"]}}}
    runs = {v: {"validation_objects": ["procedural_0020", "procedural_0024"]} for v in ("control", "both")}
    assert validation_objects(runs, card, quick=False, shipped=[]) == ("procedural_0020", "procedural_0024")
    runs["both"] = {"validation_objects": ["procedural_0020", "procedural_0025"]}
    with pytest.raises(SystemExit, match="different validation objects"):
        validation_objects(runs, card, quick=False, shipped=[])
    other = {"control": {"validation_objects": ["procedural_0001"]}}
    with pytest.raises(SystemExit, match="not default's validation objects"):
        validation_objects(other, card, quick=False, shipped=[])
    leak = {"control": {"validation_objects": [HELDOUT_OBJECTS[0]]}}
    with pytest.raises(SystemExit, match="are test objects"):
        validation_objects(leak, card, quick=True, shipped=[])
    with pytest.raises(SystemExit, match="--shipped: quality held out"):
        validation_objects({"control": runs["control"]}, card, quick=False, shipped=["quality"])


def test_the_shipped_sizes_held_out_defaults_validation_objects():
    from benchmarks.generator_levers import parse, validation_objects
    from controltac_il.checkpoint import read_json
    from controltac_il.generator.shipped import locate_checkpoint

    card = read_json(locate_checkpoint("default") / "model_card.json")
    runs = {"control": {"validation_objects": card["denoiser"]["validation"]["objects"]}}
    args = parse(["--data", "d"])
    assert args.shipped == ["frontier_tiny", "frontier_small", "quality"]
    assert parse(["--data", "d", "--quick"]).shipped == []
    held = validation_objects(runs, card, quick=False, shipped=args.shipped)
    assert held == tuple(runs["control"]["validation_objects"])


def test_the_candidates_are_default_the_shipped_sizes_and_each_trained_variant(tmp_path):
    from benchmarks.generator_levers import candidates, parse
    from controltac_il.generator.checkpoint import checkpoint_hash
    from controltac_il.generator.shipped import locate_checkpoint

    (tmp_path / "control").mkdir()
    (tmp_path / "control" / "final").symlink_to(locate_checkpoint("frontier_tiny"))  # a finished run's folder
    args = parse(["--data", "d", "--runs", str(tmp_path), "--shipped", "quality"])
    gens = candidates(args, {"control": {}})
    assert list(gens) == ["default", "quality", "control"]
    assert [g.checkpoint_hash for g in gens.values()] == [checkpoint_hash(locate_checkpoint(n))
                                                          for n in ("default", "quality", "frontier_tiny")]


def test_a_target_is_met_at_its_bound_and_the_worst_object_decides_the_third():
    from benchmarks.generator_fa_figures import TARGETS, against_targets

    scores = {"increase": {"ratio": TARGETS["increase"]}, "all": {"ratio": TARGETS["all"] + 1e-9},
              "objects": {"cube_face": {"ratio": 0.95}, "usb_c": {"ratio": 0.2}}}
    t = against_targets(scores)
    assert t["meets"] == {"increase": True, "all": False, "worst_object": False}
    assert (t["worst_object"], t["figures"]["worst_object"]) == ("cube_face", 0.95)
