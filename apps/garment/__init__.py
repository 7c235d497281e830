"""Garment recovery from a single image (*thesis* chapter 6), built on :mod:`simulator.garment`.

:mod:`.image` measures silhouettes and wrinkle densities of images, :mod:`.scenes` renders the
synthetic evaluation scenes of Fig. 6.11, :mod:`.recovery` fits the sizing G, the material C
and the pose by particle swarms over batched drapes (Alg. 3 and 4), :mod:`.tryon` dresses
another body and animates it in wind. The commands: ``python -m apps.garment.recover`` and
``python -m apps.garment.tryon``.
"""
