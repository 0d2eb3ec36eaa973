"""The wiring: the only place that knows the scene, the policy and the robot together.

    demos.py          default_demos: scripted demos from the MuJoCo scene, collected once, cached
    deploy.py         deploy(setup, policy): one control loop for the simulated robot and a real one
    train.py          train(...): train_act.py's job (dataset or embedded demos, optional ForceAugment)
    job.py            run_pipeline: the main job, collect -> augment -> train -> deploy
    experiment.py     what the imitation-learning benchmarks need of the scene and the policy
    touch_probes.py   what the cameras and the generator see of the touch-critical scene

Only the scripts (``train_act.py``, ``deploy_policy.py``, ``python -m controltac_il``) and the
benchmarks import this package, and they import nothing below it but the library (import-linter contracts in
pyproject.toml; ``tests/test_architecture.py`` for the scripts). ``ACTTrainConfig``, ``EVAL_SEED`` and ``SCENES`` are
the scripts' flags' targets.
"""

from controltac_il.app.demos import default_demos, scene_fingerprint
from controltac_il.app.deploy import (EvaluationError, check_setup, deploy, deploy_on_robot, evaluate_in_sim,
                                     load_policy)
from controltac_il.app.job import PipelineConfig, run_pipeline
from controltac_il.app.train import train_act
from envs.config import EVAL_SEED, SCENES
from policies.act.training import ACTTrainConfig

__all__ = ["ACTTrainConfig", "EVAL_SEED", "SCENES", "default_demos", "scene_fingerprint", "check_setup", "deploy", "deploy_on_robot",
           "EvaluationError", "evaluate_in_sim", "load_policy", "PipelineConfig", "run_pipeline", "train_act"]
