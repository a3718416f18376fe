"""Alias of :mod:`sim.engine.motion`, the module's home: keeps ``sim.motion`` importing (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import motion as _moved

sys.modules[__name__] = _moved
