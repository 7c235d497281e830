"""Inverse methods on the batched solver core: every candidate parameter set is a batch row."""
