"""Declarative experiment files run by ``backlash run FILE``."""
