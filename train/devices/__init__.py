"""How devices share a training epoch: the collection strategies (``strategies``, ``thread_per_device``),
the learner's state on several devices (``replicas``), several processes (``distributed``) and the
JAX-version shims (``compat``)."""
