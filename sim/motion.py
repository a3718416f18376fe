"""Alias of :mod:`sim.engine.motion`, the module's home: ``sim.motion`` imports it (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import motion as _moved

sys.modules[__name__] = _moved
