"""Dissection: topology changes of the tissue (seed 002 §3.3, seed 000 §5)."""
