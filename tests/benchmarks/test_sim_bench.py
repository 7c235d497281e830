import torch

from benchmarks import sim_bench


def test_kernels_and_their_reference_run_on_the_cpu_when_cuda_is_present(monkeypatch):
    # a GPU lease (2026-11-30) found the kernels reference built on CUDA tensors: device mismatch
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert sim_bench.bench_device("kernels") == "cpu"
    assert sim_bench.bench_device("torch") == "cuda"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert sim_bench.bench_device("torch") == "cpu"
