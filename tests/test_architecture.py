"""The house rules, enforced: import-linter contracts (pyproject.toml), module sizes, one wiring layer."""

import ast
from pathlib import Path

import pytest
from importlinter import configuration
from importlinter.application.use_cases import lint_imports

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("controltac_il", "policies", "envs", "hardware")
MAX_MODULE_LINES = 500


def test_import_contracts_hold(capsys):
    configuration.configure()
    ok = lint_imports(config_filename=str(REPO / "pyproject.toml"), cache_dir=None, no_logo=True)
    assert ok, capsys.readouterr().out


def test_every_library_package_is_under_the_library_contract():
    import tomllib

    contracts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    library = set(contracts[0]["source_modules"])
    children = {f"controltac_il.{p.stem if p.is_file() else p.name}" for p in (REPO / "controltac_il").iterdir()
                if (p.suffix == ".py" or (p / "__init__.py").is_file())}
    wiring = {"controltac_il.app", "controltac_il.__main__", "controltac_il.__init__"}
    assert children - wiring == library, "a new controltac_il module must join the library contract (or app/)"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_over_500_lines(package):
    sizes = {str(p.relative_to(REPO)): len(p.read_text().splitlines()) for p in (REPO / package).rglob("*.py")}
    assert {p: n for p, n in sizes.items() if n > MAX_MODULE_LINES} == {}


def test_scripts_only_parse_arguments_and_call_the_wiring():
    for script in ("train_act.py", "deploy_policy.py", "controltac_il/__main__.py"):
        tree = ast.parse((REPO / script).read_text())
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
        assert any(m.startswith("controltac_il.app") for m in imported), script
        wiring_elsewhere = imported & {"hardware.control_loop", "envs.sim_robot", "envs.peg_in_hole"}
        assert not wiring_elsewhere, f"{script} builds what controltac_il.app builds: {wiring_elsewhere}"
