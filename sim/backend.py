"""Alias of :mod:`sim.engine.backend`, the module's home: ``sim.backend`` imports it (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import backend as _moved

sys.modules[__name__] = _moved
