"""Pipelines that compose the chain: window datasets from logs, and training (design §9, §15)."""
