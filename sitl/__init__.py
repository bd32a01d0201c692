"""The simulated vehicle: JSBSim's F450 flown by a PX4-like cascade, speaking MAVLink like PX4,
with a world (a pad on a ground vehicle), a rendered downward camera and a lockstep clock.

It imports nothing from ``companion``; shared errors and the config reader are in
``colcommon`` (docs/sitl.md).
"""
