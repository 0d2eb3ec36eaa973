"""Robot side of controltac-il: device interfaces, adapters, safety and the shared control loop.

Modules (one job each):
    interfaces    Arm / Gripper / FrameSource / ForceSensor / Clock contracts and their small dataclasses
    safety        workspace box, largest step per period, gripper limits, watchdog
    control_loop  the 10 Hz loop (any callable policy, async inference, deadline stats, stop on fault)
    temporal_ensembling  ACT's blend of overlapping action chunks
    xarm, ur      UFACTORY xArm (+ gripper, F/T) and Universal Robots arms (+ e-series wrist F/T)
    dynamixel, robotiq   serial grippers (Protocol 2.0; Modbus RTU)
    cameras       OpenCV cameras and the GelSight Mini reader
    config, check one YAML file per setup, validated; ``python -m hardware.check setup.yaml``
    sections      the setup's device sections (robot, gripper, cameras, tactile) and the arms' reach
    fields        strict, finite pydantic field types; cross-field problems raised at their fields' paths
    fakes, fake_serial   in-memory devices and pty-served serial devices for tests and benchmarks
Vendor SDKs are imported by their adapters only, so ``import hardware`` needs none of them.
"""
