"""The companion process: it talks MAVLink to the vehicle, turns a person's or the policy's
sticks into velocity setpoints, and learns from the person (Cycle-of-Learning).

Packages: ``link`` (the vehicle), ``vision`` (camera, pad, observation), ``inputs`` (people and
scripted pilots), ``control`` (arbiter, safety, the episode loop), ``learning`` (policy,
dataset, learner, checkpoints), ``experiment`` (the paper's grid), ``rl`` (PPO baseline),
``testing`` (fakes for tests). ``app`` wires them, ``cli`` is the ``col`` command.
"""


def install_hint(extra: str) -> str:
    """How to add an optional dependency group. The distribution is not on a package index, so
    ``pip install cycle-of-learning[...]`` finds nothing: it installs from a checkout or a wheel."""
    return (f"pip install '.[{extra}]' in the project's folder (or, from a built wheel, "
            f"pip install 'cycle_of_learning-VERSION-py3-none-any.whl[{extra}]'); see docs/runtime.md")
