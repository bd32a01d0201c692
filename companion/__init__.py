"""The companion process: it talks MAVLink to the vehicle, turns a person's or the policy's
sticks into velocity setpoints, and learns from the person (Cycle-of-Learning).

Packages: ``link`` (the vehicle), ``vision`` (camera, pad, observation), ``inputs`` (people and
scripted pilots), ``control`` (arbiter, safety, the episode loop), ``learning`` (policy,
dataset, learner, checkpoints), ``experiment`` (the paper's grid), ``rl`` (PPO baseline),
``testing`` (fakes for tests). ``app`` wires them, ``cli`` is the ``col`` command.
"""
