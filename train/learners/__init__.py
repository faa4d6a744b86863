"""The learners: each in its own folder (``ppo/``: Brax PPO's networks, its loss and update, the learner
that collects and learns in one jitted epoch)."""
