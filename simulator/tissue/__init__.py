"""Tissue wing: tetrahedral organ meshes (gmsh) and the scenes the inverse methods fit.

:mod:`.meshing` builds the organ, heart and ball meshes with their regions; :mod:`.scenes`
turns them into batched static or dynamic problems on the solver core.
"""
