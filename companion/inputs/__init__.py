"""Human input sources behind one interface (:class:`~companion.inputs.base.HumanInput`).

A scripted expert, a ground station's joystick (MAVLink MANUAL_CONTROL) and a local gamepad.
"""
