"""Preprocessing, run once per scene (NumPy, trimesh): generated or loaded geometry,
tetrahedralization, clusters, truss struts, sheets and anchors, joined into one
:class:`~taichi_lap.preprocess.model_data.ModelData`; :mod:`.cache` keeps built models
on disk."""
