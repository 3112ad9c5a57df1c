"""Evaluation: run-grouped cross-validation, fold strategies, metrics and reports (design §9)."""
