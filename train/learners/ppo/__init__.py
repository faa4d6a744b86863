"""PPO on the batched env: ``networks`` (Brax's actor and critic, the training state), ``update`` (the
loss and gradient step), ``learner`` (one jitted epoch of collection and learning)."""
