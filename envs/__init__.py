"""MuJoCo peg-in-hole scene for smoke tests: tactile fingers, cameras, scripted expert, recorder.

Modules (one job each)::

    geometry.py     the scene's dimensions, one owner each: the MJCF's (peg, table, timestep, home pose)
                    read from its text, and the receptacle's (wall and floor thickness)
    config.py       PegInHoleConfig: what is rendered, sizes, randomisation ranges, workspace
    scene.py        builds the MJCF (assets/peg_in_hole.xml including assets/tactile_gripper.xml) plus
                    the receptacle sized from the config
    tactile_rig.py  pinhole ray casting (mj_multiRay) -> penetration map; pad contact forces
    peg_in_hole.py  PegInHoleEnv, a gymnasium.Env (also gymnasium.make("envs.peg_in_hole:PegInHole-v0"))
    expert.py       ScriptedExpert: approach, grasp, lift, carry, align, insert, with injected noise
    collect.py      python -m envs.collect --episodes 50 --out DIR  (ACT HDF5 episodes)
    sim_robot.py    the scene behind hardware.interfaces (Arm, Gripper, FrameSource) for ControlLoop

Importing ``envs.peg_in_hole`` sets ``MUJOCO_GL=egl`` (headless) unless already set; set it yourself
before importing ``mujoco`` anywhere else in the process.
"""
