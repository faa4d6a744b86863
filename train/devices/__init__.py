"""How devices share a training epoch: the collection strategies (``strategies`` on ``base``,
``thread_per_device``), the learner's state on several devices (``replicas``), several processes
(``distributed``; how they find each other and what a scheduler needs, ``cluster``) and the JAX-version
shims (``compat``)."""
