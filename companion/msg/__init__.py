"""The messages: the values the companion's parts hand each other, in one place.

As PX4's ``msg/`` is the only contract between its modules, these frozen, self-checking values
are what the link, the vision, the control loop and the learner share; each part imports them
from here and from nothing above it:

- :mod:`~companion.msg.snapshot`: the vehicle snapshot (the link's view of the vehicle);
- :mod:`~companion.msg.true_pose`: a simulator's true pose beside the estimate (autopilot SITLs);
- :mod:`~companion.msg.pad`: the pad as the detector found it in an image;
- :mod:`~companion.msg.observation`: the 15-value observation and its one encoding;
- :mod:`~companion.msg.command`: the joystick command (people's and policies' sticks);
- :mod:`~companion.msg.setpoint`: the velocity setpoint sent to the vehicle;
- :mod:`~companion.msg.sample`: the person's sample the dataset records;
- :mod:`~companion.msg.episode`: the episode record;
- :mod:`~companion.msg.checks`: the finite-number check every numeric field passes.

The camera frame, the one message the SITL shares with the companion, is ``colcommon.frames``
(its wire format with it).
"""
