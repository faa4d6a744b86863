"""Playing a policy's episodes and scoring them: the evaluation rollout (``rollout``; C MuJoCo workers in
``host_workers``), where a policy comes from (``policy_sources``), ``python -m train.evaluate`` as a
function (``play``), per terrain type and difficulty (``terrain_eval``) and the diagnostic plots
(``diagnostics``)."""
