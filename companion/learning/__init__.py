"""Learning from the person: the policy network and its immutable snapshots, the human dataset,
the learner (Update-Policy) and the ways it is run (budgeted, thread, process), checkpoints
(docs/learner.md)."""
