"""Taichi kernels, one file per algorithm; each docstring cites the seed equation it implements."""
