"""Test-session settings: passive OpenMP waiting (spinning threads stall each other on 2 shared cores)."""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
