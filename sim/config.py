"""Alias of :mod:`sim.engine.config`, the module's home: ``sim.config`` imports it (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import config as _moved

sys.modules[__name__] = _moved
