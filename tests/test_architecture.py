"""The house rules, enforced: import-linter contracts (pyproject.toml), module and function sizes, one wiring
layer, and tests that import this package rather than skip it."""

import ast
from pathlib import Path

import pytest
from importlinter import configuration
from importlinter.application.use_cases import lint_imports

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("controltac_il", "policies", "envs", "hardware")
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 60


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


@pytest.mark.parametrize("package", (*PACKAGES, "benchmarks", "tests"))
def test_no_module_over_500_lines(package):
    sizes = {str(p.relative_to(REPO)): len(p.read_text().splitlines()) for p in (REPO / package).rglob("*.py")}
    assert {p: n for p, n in sizes.items() if n > MAX_MODULE_LINES} == {}


def test_scripts_only_parse_arguments_and_call_the_wiring():
    for script in ("train_act.py", "deploy_policy.py", "controltac_il/__main__.py"):
        tree = ast.parse((REPO / script).read_text())
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
        assert any(m.startswith("controltac_il.app") for m in imported), script
        below = {m for m in imported if m.split(".")[0] in ("envs", "policies", "hardware")}
        assert not below, f"{script} reaches below the wiring: {below}"


@pytest.mark.parametrize("where", (*PACKAGES, "benchmarks", "tests", "plugins", "docs", "*.py"))
def test_every_function_is_under_60_lines(where):
    """Library, robot side, benchmarks, tests, the plugin, the docs' scripts and the top-level scripts alike."""
    paths = REPO.glob(where) if where == "*.py" else (REPO / where).rglob("*.py")
    long = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n >= MAX_FUNCTION_LINES:
                    long[f"{path.relative_to(REPO)}:{node.name}"] = n
    assert long == {}


def test_tests_import_this_package_instead_of_skipping_it():
    """``pytest.importorskip`` of our own package turns a broken import into silent skips."""
    offenders = [p.name for p in (REPO / "tests").glob("*.py")
                 if any(f'importorskip("{pkg}' in p.read_text() for pkg in (*PACKAGES, "benchmarks"))]
    assert offenders == []


def test_no_module_imports_a_private_name_from_another_package():
    """A leading underscore means "this package's own": the library, the benchmarks and the tests import only
    public names across packages (a test reaches a unit through a public name or the behaviour)."""
    found = []
    for path in [p for d in (*PACKAGES, "benchmarks", "tests") for p in (REPO / d).rglob("*.py")]:
        package = ".".join(path.relative_to(REPO).with_suffix("").parts[:-1])
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.rsplit(".", 1)[0] != package:
                private = [a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
                found += [f"{path.relative_to(REPO)}: {node.module}.{name}" for name in private]
    assert found == []
