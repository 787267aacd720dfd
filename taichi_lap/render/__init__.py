"""Deferred physically based rendering of a session (seed 000 §6)."""
