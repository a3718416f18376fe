"""Alias of :mod:`sim.engine.scene`, the module's home: ``sim.scene`` imports it (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import scene as _moved

sys.modules[__name__] = _moved
