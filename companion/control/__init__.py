"""Who flies and how a command reaches the vehicle: joystick -> setpoint mapping, the arbiter
(person or policy), safety (geofence, limiter) and the episode loop that ties them together."""
