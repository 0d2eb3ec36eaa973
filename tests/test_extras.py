"""The install's optional parts: the core imports without any robot SDK or MuJoCo, an adapter without its extra is
one line naming the extra to install, and pyproject.toml's extras, scripts and packages say the same."""

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from controltac_il.cli import guard
from controltac_il.extras import EXTRAS, MissingExtra, require

REPO = Path(__file__).resolve().parents[1]
SDKS = ("rtde_control", "rtde_receive", "xarm", "dynamixel_sdk", "serial", "mujoco", "gymnasium")


PROBE = """
import sys
for m in SDKS:
    sys.modules[m] = None
import controltac_il.augment, controltac_il.augment.cli, controltac_il.app.train_cli, controltac_il.calibrate.cli
import controltac_il.app.deploy, controltac_il.app.deploy_cli, controltac_il.__main__  # a robot deploys without MuJoCo
import hardware.config
print(sorted(m for m, v in sys.modules.items() if v is not None and m.split('.')[0] in SDKS))
from controltac_il.extras import MissingExtra
for name in ("hardware.dynamixel", "hardware.robotiq", "envs.scene"):
    try:
        __import__(name)
    except MissingExtra as exc:
        print(exc)
from hardware.ur import URArm
from hardware.xarm import XArm
for arm in (URArm("127.0.0.1"), XArm("127.0.0.1")):  # loopback: no traffic leaves, and none is sent
    try:
        arm.connect()
    except MissingExtra as exc:
        print(exc)
"""


@pytest.fixture(scope="module")
def without_sdks() -> list[str]:
    """What PROBE prints in a fresh interpreter where every robot SDK and MuJoCo fail to import."""
    run = subprocess.run([sys.executable, "-c", f"SDKS = {SDKS!r}\n" + PROBE], cwd=REPO, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stderr
    return run.stdout.strip().splitlines()


def test_the_augmentation_library_the_training_and_deploy_wiring_import_without_sdks_or_mujoco(without_sdks):
    assert without_sdks[0] == "[]"


def test_an_adapter_without_its_extra_names_the_extra_and_an_arm_asks_before_any_network(without_sdks):
    assert without_sdks[1:] == [
        "the Dynamixel gripper needs dynamixel-sdk and pyserial, which are not installed: "
        "pip install 'controltac-il[dynamixel]'",
        "the Robotiq gripper needs pyserial, which is not installed: pip install 'controltac-il[robotiq]'",
        "the MuJoCo scene needs mujoco and gymnasium, which are not installed: pip install 'controltac-il[sim]'",
        "the UR arm needs ur-rtde, which is not installed: pip install 'controltac-il[ur]'",
        "the xArm needs xarm-python-sdk, which is not installed: pip install 'controltac-il[xarm]'"]


def test_a_missing_extra_in_a_command_is_one_line_and_exit_2(capsys):
    def job():
        raise MissingExtra("the UR arm needs ur-rtde, which is not installed: pip install 'controltac-il[ur]'")

    assert guard("deploy", job) == 2
    assert capsys.readouterr().err == ("deploy: error: the UR arm needs ur-rtde, which is not installed: "
                                       "pip install 'controltac-il[ur]'\n")


def test_require_passes_through_a_present_module_and_a_broken_one_and_refuses_an_unknown_extra(tmp_path, monkeypatch):
    assert require("json", "sim", "x").dumps([1]) == "[1]"
    (tmp_path / "broken_sdk.py").write_text("import its_missing_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError, match="its_missing_dependency"):  # installed but broken: not an extra
        require("broken_sdk", "sim", "x")
    with pytest.raises(MissingExtra, match=r"pip install 'controltac-il\[sim\]'"):
        require("no_such_sdk.wrapper", "sim", "x")
    with pytest.raises(KeyError, match="unknown extra 'gpu'"):
        require("json", "gpu", "x")


def test_pyproject_extras_scripts_and_packages_agree_with_the_code():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    extras = project["project"]["optional-dependencies"]
    for extra, dists in EXTRAS.items():
        assert sorted(d.split(">")[0] for d in extras[extra]) == sorted(dists), extra
    assert extras["all"] == [f"controltac-il[{','.join(EXTRAS)}]"]
    core = " ".join(project["project"]["dependencies"])
    assert not any(d in core for ds in EXTRAS.values() for d in ds) and "contrib" not in core
    assert "benchmarks*" not in project["tool"]["setuptools"]["packages"]["find"]["include"]
    for target in project["project"]["scripts"].values():
        module, func = target.split(":")
        assert (REPO / (module.replace(".", "/") + ".py")).is_file(), target
        assert f"\ndef {func}(" in (REPO / (module.replace(".", "/") + ".py")).read_text(), target
