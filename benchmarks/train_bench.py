"""Training and inference throughput of the material classifiers, in clips/s.

``python -m benchmarks.train_bench [--batch 16] [--steps 12] [--device auto]``

Each method of configs/model (CNN+LSTM, baseline 1 on clips' frames, baseline 2, CNN+LSTM on
frame differences) is built
from its Hydra config with the default encoder and fed synthetic clips of the dataset's
shape (10 frames, 3 x 112 x 112): a training step is forward + cross-entropy + backward +
AdamW step (``train`` mode); inference is a no-grad forward (``eval`` mode). Medians over
``steps`` timed steps after two warm-ups. On CUDA the default trainer's bf16 autocast is
used. Data loading is not included (decoded clips are cached in memory during training; see
``datasets.clip_dataset``).

The last line is JSON: ``train_clips_per_s`` and ``infer_clips_per_s`` of the default
method (CNN+LSTM), ``device``, and ``methods`` with every method's figures.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from simulator.cloth.material import CLASS_COUNT

CONFIGS = str(Path(__file__).resolve().parents[1] / "configs")
METHODS = ("cnn_lstm", "base1", "base2", "cnn_lstm_diff")


def _build(method: str, encoder: str):
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    overrides = [f"model={method}", f"encoder={encoder}", "paths.output_dir=/tmp"]
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(config_name="train", overrides=overrides)
    if method == "base2":
        cfg.model.net.encoder_checkpoint = None  # random frozen encoder: same cost
    return instantiate(cfg.model, net={"num_classes": CLASS_COUNT})  # train.py: the data's


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def _median_rate(step, clips: int, steps: int, device: torch.device) -> float:
    for _ in range(2):
        step()
    _sync(device)
    times = []
    for _ in range(steps):
        start = time.perf_counter()
        step()
        _sync(device)
        times.append(time.perf_counter() - start)
    return clips / statistics.median(times)


def measure(
    method: str,
    *,
    batch: int,
    frames: int,
    size: int,
    steps: int,
    device: torch.device,
    encoder: str = "alexnet5",
) -> dict:
    """Train and inference clips/s of one method."""
    torch.manual_seed(0)
    module = _build(method, encoder).to(device)
    video = torch.rand(batch, frames, 3, size, size, device=device)
    labels = torch.randint(0, CLASS_COUNT, (batch,), device=device)
    params = [p for p in module.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=1e-3)
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=device.type == "cuda")

    def train_step():
        module.train()
        optimizer.zero_grad(set_to_none=True)
        with autocast:
            if method == "base1":  # trained on frames: the same pixels, one frame per sample
                loss = module.loss(module(video.flatten(0, 1)), labels.repeat_interleave(frames))
            else:
                loss = module.loss(module(video), labels)
        loss.backward()
        optimizer.step()

    @torch.no_grad()
    def infer_step():
        module.eval()
        with autocast:
            module(video)

    return {
        "train_clips_per_s": _median_rate(train_step, batch, steps, device),
        "infer_clips_per_s": _median_rate(infer_step, batch, steps, device),
        "params_trainable": sum(p.numel() for p in params),
    }


def main(argv: list[str] | None = None) -> dict:
    """Print a table and the JSON line; returns the JSON dict."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--size", type=int, default=112)
    parser.add_argument("--steps", type=int, default=12)
    parser.add_argument("--encoder", default="alexnet5")
    parser.add_argument("--device", default="auto", help="auto | cpu | cuda")
    args = parser.parse_args(argv)
    name = args.device
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(name)
    label = (
        torch.cuda.get_device_name(device)
        if device.type == "cuda"
        else (f"CPU, {torch.get_num_threads()} threads")
    )
    results = {}
    print(f"device: {label}; batch {args.batch} clips of {args.frames} x 3 x {args.size}^2")
    print(f"{'method':10s} {'train clips/s':>14s} {'infer clips/s':>14s} {'trainable':>10s}")
    for method in METHODS:
        r = measure(
            method,
            batch=args.batch,
            frames=args.frames,
            size=args.size,
            steps=args.steps,
            device=device,
            encoder=args.encoder,
        )
        results[method] = r
        print(
            f"{method:10s} {r['train_clips_per_s']:14.1f} {r['infer_clips_per_s']:14.1f} "
            f"{r['params_trainable']:10d}"
        )
    summary = {
        "train_clips_per_s": round(results["cnn_lstm"]["train_clips_per_s"], 2),
        "infer_clips_per_s": round(results["cnn_lstm"]["infer_clips_per_s"], 2),
        "device": label,
        "encoder": args.encoder,
        "methods": {
            m: {k: round(v, 2) if isinstance(v, float) else v for k, v in r.items()}
            for m, r in results.items()
        },
    }
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
