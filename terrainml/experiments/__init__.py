"""Experiments above the chain: the closed loop, the slip-map laps and the simulated recipes.

Nothing in the chain (io → estimation → features → models → lookup → stream → control) imports
this package.
"""
