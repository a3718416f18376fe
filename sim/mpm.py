"""Alias of :mod:`sim.engine.mpm`, the module's home: ``sim.mpm`` imports it (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import mpm as _moved

sys.modules[__name__] = _moved
