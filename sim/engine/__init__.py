"""The simulator engine: MLS-MPM water, kinematic colliders and their scene description, nothing of pouring.

Modules: ``config`` (``SimConfig``), ``backend`` (Taichi's initialisation), ``physics`` (the water model's
Taichi functions), ``scene`` (bodies, shapes, water blocks), ``motion`` (kinematic profiles and a path
follower), ``mpm`` (the production solver, batched, CPU/GPU), ``diff_mpm`` (the differentiable solver),
``render`` (frames and GIFs). The pouring task (worlds, skills, execution, differentiable pours) lives in
the modules of ``sim`` beside this package and builds on it; nothing here imports them
(tests/test_sim_layers.py).
"""
