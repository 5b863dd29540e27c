"""Training: one run of one entrant (env + agent + periodic greedy tests) into one job folder.

Modules, in the order data flows through them:

- ``presets``: named settings bundles (``paper``, ``best``, ...); ``run_spec``: the frozen,
  validated ``RunSpec`` that ``train``, tournaments and tune studies all build one way.
- ``envs``: the run's envs (training, tests, ``eval``, ``replay``); ``demos``: the follower's laps
  as demonstrations; ``collect``: driving cars into the replay buffer; ``budget``: the CPU clock
  and the rule that ends a run early; ``evaluate``: the greedy tests.
- ``loop``: one run, written through ``results.folder``; ``checkpoint``: a run's checkpoint read
  back with its run spec; ``replay``: one test of a trained actor driven again (a GIF of its lap).
"""
