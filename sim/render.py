"""Alias of :mod:`sim.engine.render`, the module's home: ``sim.render`` imports it (attributes set through either
name are the same) until the callers outside sim/ import the new path."""

import sys

from sim.engine import render as _moved

sys.modules[__name__] = _moved
