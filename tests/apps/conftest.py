"""The applications' tests share the datasets' tiny generated dataset."""

from tests.datasets.conftest import tiny_dataset  # noqa: F401  (a session fixture)
