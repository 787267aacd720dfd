"""Model building: geometry, tetrahedralization, clusters, struts, anchors (NumPy, run once)."""
