"""What the companion and the SITL both need and neither owns: the project's error hierarchy
(:mod:`colcommon.errors`), the TOML-to-pydantic config reader (:mod:`colcommon.configio`) and the
containers' health probes (:mod:`colcommon.health`).

It imports neither ``companion`` nor ``sitl``, so the simulated vehicle installs and reads on
its own.
"""
