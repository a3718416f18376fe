"""The water-pouring simulator: the engine (``sim.engine``: MLS-MPM water, colliders, both solvers) and the
pouring task on it (``world``: the worlds and their scenes; ``skills``: move and pour as cup schedules;
``execute``: batched trajectories; ``problems``; ``contact``: contact prediction for the planner; ``diff`` and
``diff_schedule``: differentiable pours). The engine imports nothing of the task (``tests/test_sim_layers.py``)."""
