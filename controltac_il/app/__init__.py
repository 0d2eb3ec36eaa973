"""The wiring: the only place that knows the scene, the policy and the robot together.

    demos.py          default_demos: scripted demos from the MuJoCo scene, collected once, cached
    deploy.py         deploy(setup, policy): one control loop for the simulated robot and a real one
    train.py          train(...): train_act.py's job (dataset or embedded demos, optional ForceAugment)
    job.py            run_pipeline: the main job, collect -> augment -> train -> deploy
    job_config.py     PipelineConfig: the main job's settings (light: the CLI's --help reads them)
    experiment.py     what the imitation-learning benchmarks need of the scene and the policy
    touch_probes.py   what the cameras and the generator see of the touch-critical scene

Only the scripts (``train_act.py``, ``deploy_policy.py``, ``python -m controltac_il``) and the
benchmarks import this package, and they import nothing below it but the library (import-linter contracts in
pyproject.toml; ``tests/test_architecture.py`` for the scripts). ``ACTTrainConfig``, ``DEMO_EPISODES``, ``EVAL_SEED`` and
``SCENES`` are the scripts' flags' targets.
"""

from controltac_il.lazy import exports

_EXPORTS = {**dict.fromkeys(("default_demos", "scene_fingerprint"), "controltac_il.app.demos"),
            **dict.fromkeys(("EvaluationError", "check_setup", "deploy", "deploy_on_robot", "evaluate_in_sim",
                             "load_policy"), "controltac_il.app.deploy"),
            "PipelineConfig": "controltac_il.app.job_config", "run_pipeline": "controltac_il.app.job",
            "train_act": "controltac_il.app.train", **dict.fromkeys(("DEMO_EPISODES", "EVAL_SEED", "SCENES"), "envs.config"),
            "ACTTrainConfig": "policies.act.training"}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
