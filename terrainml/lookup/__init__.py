"""Desired-slip lookup (SYSTEM §10) and the terramechanics models it is built on (SYSTEM §6.1-6.2)."""
