"""What the companion and the SITL both need and neither owns: the project's error hierarchy
(:mod:`colcommon.errors`) and the TOML-to-pydantic config reader (:mod:`colcommon.configio`).

It imports neither ``companion`` nor ``sitl``, so the simulated vehicle installs and reads on
its own.
"""
