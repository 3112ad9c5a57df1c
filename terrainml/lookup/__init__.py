"""Desired-slip lookup (design §10) and the terramechanics models it is built on (design §6.1-6.2)."""
