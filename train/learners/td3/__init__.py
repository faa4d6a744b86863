"""TD3 (FastTD3) for thousands of envs on the device: its config section, networks, replay buffer, update,
learner and learner state as the run sees it (``run.learner: td3``)."""
