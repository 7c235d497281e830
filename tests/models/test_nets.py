"""Shapes, gradients, freezing and weight loading of the encoders and clip nets."""

import functools
import logging

import pytest
import torch

from models.components import video_nets
from models.components.frame_encoder import ENCODERS, FrameEncoder
from models.components.video_nets import frame_differences, load_encoder_state

CLASSES = 54
"""The thesis's classes; the nets take the data's class count (num_classes) as an argument."""
CNNLSTMNet = functools.partial(video_nets.CNNLSTMNet, num_classes=CLASSES)
FramePoolNet = functools.partial(video_nets.FramePoolNet, num_classes=CLASSES)


def _clips(batch=2, steps=3, size=64, seed=0):
    return torch.rand(batch, steps, 3, size, size, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("name", ENCODERS)
def test_every_encoder_in_every_net_gives_logits_and_gradients(name):
    torch.manual_seed(0)
    encoder = FrameEncoder(name, feature_dim=16, width=0.25)
    assert encoder(torch.rand(5, 3, 64, 64)).shape == (5, 16)
    for net in (CNNLSTMNet(encoder, hidden_size=8), FramePoolNet(encoder, num_classes=54)):
        video = _clips().requires_grad_(True)
        logits = net(video)
        assert logits.shape == (2, 54) and torch.isfinite(logits).all()
        logits.sum().backward()
        assert video.grad is not None and video.grad.abs().sum() > 0


def test_frame_pool_net_mean_of_frame_logits_and_single_frames():
    torch.manual_seed(0)
    net = FramePoolNet(FrameEncoder(feature_dim=8, width=0.25, dropout=0.0)).eval()
    video = _clips(steps=4)
    per_frame = torch.stack([net(video[:, t]) for t in range(4)], dim=1)
    torch.testing.assert_close(net(video), per_frame.mean(1), rtol=1e-5, atol=1e-5)


def test_lstm_readouts_and_order_sensitivity():
    torch.manual_seed(0)
    video = _clips(steps=5)
    for readout in ("mean", "last"):
        net = CNNLSTMNet(
            FrameEncoder(feature_dim=8, width=0.25, dropout=0.0), hidden_size=8, readout=readout
        ).eval()
        reversed_video = video.flip(1)
        assert not torch.allclose(net(video), net(reversed_video))  # it sees the order


def test_fc6_norm_keeps_every_fc6_unit_alive():
    torch.manual_seed(0)
    frames = torch.rand(32, 3, 64, 64)
    for fc6_norm in (False, True):
        encoder = FrameEncoder(feature_dim=16, width=0.25, dropout=0.0, fc6_norm=fc6_norm)
        with torch.no_grad():
            linear = encoder.fc6[0]
            linear.bias.fill_(-10.0)  # what a run of large updates can do to fc6's biases
            features = encoder.train()(frames)
        dead = int((features.amax(0) == 0).sum())
        assert dead == (0 if fc6_norm else 16), fc6_norm
    assert isinstance(encoder.fc6[1], torch.nn.BatchNorm1d)


def test_frame_differences_values_and_invariance_to_static_content():
    video = torch.zeros(1, 3, 3, 2, 2)
    video[:, 1] = 0.25  # +0.25, then -0.25: sqrt lifts both to 0.5 from mid-grey
    diff = frame_differences(video)
    assert diff.shape == (1, 2, 3, 2, 2)
    torch.testing.assert_close(diff[0, 0], torch.full((3, 2, 2), 0.75))
    torch.testing.assert_close(diff[0, 1], torch.full((3, 2, 2), 0.25))
    assert diff.min() >= 0 and diff.max() <= 1
    moving = _clips(steps=4)
    static = torch.rand(1, 1, 3, 64, 64).clamp(0, 0.5)  # a texture that does not move
    torch.manual_seed(0)
    net = CNNLSTMNet(
        FrameEncoder(feature_dim=8, width=0.25, dropout=0.0), hidden_size=8, inputs="frame_diff"
    ).eval()
    still = static.expand(2, 4, 3, 64, 64)
    brighter = still + 0.3  # another static background: the same (zero) differences
    torch.testing.assert_close(net(still), net(brighter))
    assert not torch.allclose(net(moving * 0.5), net(still))
    with pytest.raises(ValueError, match="frame_diff input needs clips of >= 2 frames"):
        net(_clips(steps=1))


def test_two_stream_reads_frames_and_differences_from_their_own_checkpoints(tmp_path):
    torch.manual_seed(0)
    base1 = FramePoolNet(FrameEncoder(feature_dim=8, width=0.25, dropout=0.0))
    diff = CNNLSTMNet(
        FrameEncoder(feature_dim=6, width=0.25, dropout=0.0), hidden_size=8, inputs="frame_diff"
    )
    paths = {}
    for name, net in (("base1", base1), ("diff", diff)):
        paths[name] = tmp_path / f"{name}.ckpt"
        torch.save(
            {"state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, paths[name]
        )
    torch.manual_seed(1)
    net = CNNLSTMNet(
        FrameEncoder(feature_dim=8, width=0.25, dropout=0.0),
        hidden_size=8,
        inputs="two_stream",
        encoder_checkpoint=str(paths["base1"]),
        motion_encoder=FrameEncoder(feature_dim=6, width=0.25, dropout=0.0),
        motion_encoder_checkpoint=str(paths["diff"]),
    ).eval()
    assert net.lstm.input_size == 8 + 6
    for mine, theirs in ((net.encoder, base1.encoder), (net.motion_encoder, diff.encoder)):
        for key, value in theirs.state_dict().items():
            torch.testing.assert_close(mine.state_dict()[key], value, msg=key)
    video = _clips(steps=4).requires_grad_(True)
    logits = net(video)
    assert logits.shape == (2, 54)
    logits.sum().backward()
    assert all(p.grad is not None for p in net.motion_encoder.parameters() if p.requires_grad)
    # The RGB stream reads frames 2..T; a change of frame 1 alone reaches only the differences.
    with torch.no_grad():
        features = net.encoder(video[:, 1:].flatten(0, 1)).view(2, 3, -1)
        moved = video.detach().clone()
        moved[:, 0] = 1 - moved[:, 0]
        assert not torch.allclose(net(moved), net(video))
        torch.testing.assert_close(net.encoder(moved[:, 1:].flatten(0, 1)).view(2, 3, -1), features)
    with pytest.raises(ValueError, match="motion_encoder is needed"):
        CNNLSTMNet(FrameEncoder(feature_dim=4, width=0.25), inputs="two_stream")
    with pytest.raises(ValueError, match="motion_encoder is needed"):
        CNNLSTMNet(
            FrameEncoder(feature_dim=4, width=0.25),
            motion_encoder=FrameEncoder(feature_dim=4, width=0.25),
        )


def test_the_class_count_is_an_argument_of_every_net():
    encoder = FrameEncoder(feature_dim=4, width=0.25)
    for net in (video_nets.CNNLSTMNet, video_nets.FramePoolNet):
        with pytest.raises(TypeError, match="num_classes"):
            net(encoder)
        assert net(encoder, num_classes=10)(_clips(steps=2, size=32)).shape == (2, 10)


def test_bad_arguments_name_the_field():
    with pytest.raises(ValueError, match="encoder name must be one of"):
        FrameEncoder("vgg99")
    with pytest.raises(ValueError, match="feature_dim"):
        FrameEncoder(feature_dim=0)
    with pytest.raises(ValueError, match="readout"):
        CNNLSTMNet(FrameEncoder(feature_dim=4, width=0.25), readout="max")
    with pytest.raises(ValueError, match="hidden_size"):
        CNNLSTMNet(FrameEncoder(feature_dim=4, width=0.25), hidden_size=0)
    with pytest.raises(ValueError, match="inputs must be one of"):
        CNNLSTMNet(FrameEncoder(feature_dim=4, width=0.25), inputs="flow")
    with pytest.raises(ValueError, match=r"video must have shape \(B, T, 3, H, W\)"):
        CNNLSTMNet(FrameEncoder(feature_dim=4, width=0.25))(torch.rand(2, 3, 32, 32))


def test_frozen_encoder_from_checkpoint_gets_no_gradient_and_stays_in_eval(tmp_path):
    torch.manual_seed(0)
    base1 = FramePoolNet(FrameEncoder(feature_dim=8, width=0.25))
    path = tmp_path / "base1.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in base1.state_dict().items()}}, path)
    torch.manual_seed(1)
    base2 = CNNLSTMNet(
        FrameEncoder(feature_dim=8, width=0.25),
        hidden_size=8,
        freeze_encoder=True,
        encoder_checkpoint=str(path),
    )
    for key, value in base1.encoder.state_dict().items():
        torch.testing.assert_close(base2.encoder.state_dict()[key], value, msg=key)
    base2.train()
    assert not base2.encoder.training and base2.lstm.training
    base2(_clips(size=32)).sum().backward()
    assert all(p.grad is None for p in base2.encoder.parameters())
    assert base2.lstm.weight_ih_l0.grad is not None


def test_missing_or_foreign_encoder_checkpoint_is_a_clear_error(tmp_path):
    encoder = FrameEncoder(feature_dim=8, width=0.25)
    with pytest.raises(FileNotFoundError, match="baseline 1"):
        load_encoder_state(encoder, tmp_path / "nope.ckpt")
    torch.save({"state_dict": {"net.other.weight": torch.zeros(1)}}, tmp_path / "x.ckpt")
    with pytest.raises(ValueError, match="no weights matching"):
        load_encoder_state(encoder, tmp_path / "x.ckpt")
    for trained, loading in ((False, True), (True, False)):  # fc6_norm differs either way
        base1 = FramePoolNet(FrameEncoder(feature_dim=8, width=0.25, fc6_norm=trained))
        state = {f"net.{k}": v for k, v in base1.state_dict().items()}
        torch.save({"state_dict": state}, tmp_path / "b1.ckpt")
        other = FrameEncoder(feature_dim=8, width=0.25, fc6_norm=loading)
        with pytest.raises(ValueError, match="fc6_norm"):
            load_encoder_state(other, tmp_path / "b1.ckpt")


def test_pretrained_weights_only_from_local_files(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    with caplog.at_level(logging.WARNING):
        FrameEncoder("resnet18", feature_dim=8, pretrained=True)
    assert "not found" in caplog.text and "nothing is downloaded" in caplog.text
    source = FrameEncoder("resnet18", feature_dim=8)
    weights = tmp_path / "resnet18.pth"
    torch.save(source.trunk.state_dict(), weights)
    loaded = FrameEncoder("resnet18", feature_dim=8, pretrained=str(weights))
    assert loaded.pretrained_from == str(weights)
    torch.testing.assert_close(loaded.trunk.conv1.weight, source.trunk.conv1.weight)
