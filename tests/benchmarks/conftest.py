"""The tiny generated dataset of the dataset tests, for the probe and oracle scripts."""

from tests.datasets.conftest import tiny_dataset

__all__ = ["tiny_dataset"]
