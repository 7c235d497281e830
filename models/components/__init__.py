"""Nets (no Lightning here): per-frame encoders and the clip classifiers built on them."""

from .frame_encoder import ENCODERS, FrameEncoder
from .video_nets import CNNLSTMNet, FramePoolNet

__all__ = ["ENCODERS", "CNNLSTMNet", "FrameEncoder", "FramePoolNet"]
