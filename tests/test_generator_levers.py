"""benchmarks.generator_levers: each variant's command is default's own recipe with its lever, nothing else."""

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
