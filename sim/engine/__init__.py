"""The simulator engine: MLS-MPM water and kinematic colliders, nothing of pouring.

Modules: ``config`` (``SimConfig``), ``backend`` (Taichi's initialisation), ``physics`` (the water model's
Taichi functions), ``stencil`` (particle to grid, the grid update, grid to particle) and ``colliders`` (the
tank walls and kinematic bodies: storage and the contact query), which both solvers call: ``mpm`` (the
production solver, batched, CPU/GPU) and ``diff_mpm`` (the differentiable solver, which takes its geometry
as arguments); ``scene`` (bodies, shapes, water blocks), ``motion`` (kinematic profiles and a path follower),
``render`` (frames and GIFs). The pouring task (worlds, skills, execution, differentiable pours) lives in the
modules of ``sim`` beside this package and builds on it; nothing here imports them (tests/test_sim_layers.py).
"""
