"""Designed experiments: the plan a run executes while balancing (plan.py)."""
