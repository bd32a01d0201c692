"""Pictures after a run: ``flight.png`` (top view of every episode's track and touchdown,
coloured by who flew) and ``episode_NNN.mp4`` (the last episode's camera with the HUD)."""
