"""Tooling: benchmarks, validation, checks and demos, run as ``python -m benchmarks.X`` from the repository
root (``README.md`` here lists them; ``results/`` holds the JSON that BENCHMARKS.md cites).

Not part of the installed product: no product package (``sim``, ``mde``, ``planner``, ``dynamics``,
``active``, ``safeio``, ``task``) imports this package. The tools themselves may import anything,
including the test doubles in ``tests/doubles`` (``benchmarks.planner`` times the planner with them).
``peers/`` holds the Genesis comparison, run as scripts (``bash benchmarks/peers/genesis.sh``).
"""
