"""What the companion and the SITL both need and neither owns: the project's error hierarchy
(:mod:`colcommon.errors`), the TOML-to-pydantic config reader (:mod:`colcommon.configio`), the
containers' health probes (:mod:`colcommon.health`), and the messages both sides exchange: the
camera frame and its wire format (:mod:`colcommon.frames`) and the camera's geometry
(:mod:`colcommon.camera_geometry`).

It imports neither ``companion`` nor ``sitl``, so the simulated vehicle installs and reads on
its own.
"""
