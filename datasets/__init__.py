"""Cloth video datasets (thesis 7.6-7.7.1): generation, shards, manifest, torch loaders.

Data flow: :class:`~datasets.spec.DatasetSpec` -> :func:`~datasets.plan.plan_units` ->
:func:`~datasets.generation.generate_dataset` (simulate, render, shard) -> manifest ->
:class:`~datasets.clip_dataset.ClothClipDataset` /
:class:`~datasets.datamodule.ClothVideoDataModule`.
Real footage: :class:`~datasets.real_video.RealVideoDataset` /
:class:`~datasets.real_datamodule.RealVideoDataModule`. Importing a submodule loads
only what it needs (the DataModule needs lightning, generation needs the renderer).
"""
