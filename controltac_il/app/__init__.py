"""The wiring: the only place that knows the scene, the policy and the robot together.

    demos.py          default_demos: scripted demos from the MuJoCo scene, collected once, cached
    augment_stage.py  ForceAugmentStage: train set -> ForceAugment copies (what train_act --augment runs)
    deploy.py         deploy(setup, policy): one control loop for the simulated robot and a real one
    train.py          train(...): train_act.py's job (dataset or embedded demos, optional ForceAugment)
    job.py            run_pipeline: the main job, collect -> augment -> train -> deploy

Only the scripts (``train_act.py``, ``deploy_policy.py``, ``python -m controltac_il``) and the
benchmarks import this package (an import-linter contract in pyproject.toml).
"""

from controltac_il.app.augment_stage import ForceAugmentStage
from controltac_il.app.demos import default_demos, scene_fingerprint
from controltac_il.app.deploy import check_setup, deploy, deploy_on_robot, evaluate_in_sim, load_policy
from controltac_il.app.job import PipelineConfig, run_pipeline
from controltac_il.app.train import train_act

__all__ = ["ForceAugmentStage", "default_demos", "scene_fingerprint", "check_setup", "deploy", "deploy_on_robot",
           "evaluate_in_sim", "load_policy", "PipelineConfig", "run_pipeline", "train_act"]
