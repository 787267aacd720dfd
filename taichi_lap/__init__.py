"""taichi-lap: a GPU-first laparoscopic surgery simulator on Taichi.

The public surface is small: :mod:`taichi_lap.runtime` (backend selection),
:mod:`taichi_lap.scene` (scene files), :mod:`taichi_lap.preprocess` (scene -> model data, cached),
:mod:`taichi_lap.sim` (Model / State / Control / Solver) and the ``taichi-lap``
command line (:mod:`taichi_lap.cli`).
"""

__version__ = "0.1.0"
