"""common: field checks name the field and the allowed values; entry points print
one line for a user error and keep the traceback for a programming error."""

import math

import pytest
import torch
from hydra.errors import InstantiationException

from common.checks import (
    check_bool,
    check_choice,
    check_device,
    check_float,
    check_int,
    require_cuda,
)
from common.commands import report_user_errors
from common.configs import check_node, config_errors
from common.errors import InputError
from simulator.cloth.material import MaterialError, check_class_ids


def test_check_int_accepts_integers_and_refuses_the_rest():
    assert check_int(3, "n") == 3 and check_int(4.0, "n") == 4 and check_int(" 5 ", "n") == 5
    for bad in ("abc", 1.5, True, None, [1]):
        with pytest.raises(InputError, match=r"^n must be an integer in \[0, 9\], got "):
            check_int(bad, "n", 0, 9)
    with pytest.raises(InputError, match=r"^n must be an integer >= 1, got 0$"):
        check_int(0, "n", 1)
    with pytest.raises(InputError, match=r"^n must be an integer <= 2, got 3$"):
        check_int(3, "n", high=2)


def test_check_float_refuses_text_nan_and_out_of_range():
    assert check_float("2.5", "x") == 2.5 and check_float(1, "x", 0, low_open=True) == 1.0
    for bad in ("abc", math.nan, math.inf, True, None):
        with pytest.raises(InputError, match=r"^x must be a finite number"):
            check_float(bad, "x")
    with pytest.raises(InputError, match=r"^x must be a number > 0, got 0$"):
        check_float(0, "x", 0, low_open=True)
    with pytest.raises(InputError, match=r"^x must be a number in \[0, 1\], got 1.5$"):
        check_float(1.5, "x", 0, 1)


def test_check_choice_bool_and_class_ids():
    assert check_choice("obj", "export", ("obj", "ply")) == "obj"
    with pytest.raises(InputError, match=r"^export must be one of obj, ply; got 'gif'$"):
        check_choice("gif", "export", ("obj", "ply"))
    assert check_bool(False, "flag") is False
    with pytest.raises(InputError, match=r"^flag must be true or false, got 'yes'$"):
        check_bool("yes", "flag")
    assert check_class_ids([0, 26.0, 53]) == (0, 26, 53)
    for bad, where in (
        ([1.7], r"classes\[0\]"),
        ([0, 54], r"classes\[1\]"),
        ([0, "a"], r"classes\[1\]"),
        ([True], r"classes\[0\]"),
    ):
        with pytest.raises(InputError, match=rf"^{where} must be an integer class id in \[0, 53\]"):
            check_class_ids(bad)
    for bad in (5, "0,1", [], {"a": 1}):
        with pytest.raises(InputError, match=r"^classes must be a (non-empty )?list of"):
            check_class_ids(bad)


def test_check_device_and_cuda_requests():
    assert check_device("auto", "sim.device") == "auto" and check_device("CPU", "d") == "cpu"
    with pytest.raises(InputError, match=r"^sim.device must be one of auto, cpu, cuda, cuda:N"):
        check_device("tpu", "sim.device")
    if torch.cuda.is_available():
        assert check_device("cuda", "sim.device") == "cuda"
        require_cuda("trainer.accelerator=gpu", "use trainer=cpu")
    else:
        with pytest.raises(InputError, match=r"^sim.device=cuda asks for CUDA, but this machine"):
            check_device("cuda", "sim.device")
        with pytest.raises(
            InputError, match=r"^trainer.accelerator=gpu asks for CUDA.*trainer=cpu$"
        ):
            require_cuda("trainer.accelerator=gpu", "use trainer=cpu")


SIM = {
    "_target_": "simulator.cloth.rollout.SimSettings",
    "max_dt": 0.005,
    "dtype": "float64",
    "newton": {"_target_": "simulator.solvers.NewtonSettings", "max_iters": 1},
}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"max_dt": "abc"}, "sim.max_dt must be a number, got 'abc'"),
        ({"max_dt": True}, "sim.max_dt must be a number, got True"),
        ({"settle_max_dt": "x"}, "sim.settle_max_dt must be a number or null, got 'x'"),
        (
            {"newton": {**SIM["newton"], "max_iters": 1.5}},
            "sim.newton.max_iters must be an integer, got 1.5",
        ),
        ({"fast": True}, "sim.fast is not a field of sim; allowed: max_dt, newton,"),
    ],
)
def test_check_node_types_fields_against_the_target(change, message):
    check_node(SIM, "sim")  # the valid node passes
    with pytest.raises(InputError, match=r"^" + message.replace("(", r"\(").replace(")", r"\)")):
        check_node({**SIM, **change}, "sim")


def test_check_node_reads_literals_lists_and_factories():
    node = {"_target_": "lightning.pytorch.Trainer", "precision": "bf17", "max_epochs": 2}
    with pytest.raises(InputError, match=r"^trainer.precision must be one of 64, 32, 16, .*bf16"):
        check_node(node, "trainer")
    camera = {"_target_": "render.camera.CameraSpec.wind", "width": "wide"}
    with pytest.raises(InputError, match=r"^render.camera.width must be an integer, got 'wide'"):
        check_node(camera, "render.camera")
    wind = {"_target_": "simulator.cloth.scenes.ScenarioWind", "wind_speeds": [1, "a"]}
    with pytest.raises(InputError, match=r"^scenario.wind_speeds must be a list of numbers"):
        check_node(wind, "scenario")
    with pytest.raises(InputError, match=r"^x._target_: cannot import 'nowhere.Thing'"):
        check_node({"_target_": "nowhere.Thing"}, "x")
    check_node({"_target_": "torch.optim.AdamW", "_partial_": True, "lr": 1e-3}, "optimizer")
    with pytest.raises(InputError, match=r"^optimizer.lr must be a number, got 'abc'"):
        check_node({"_target_": "torch.optim.AdamW", "_partial_": True, "lr": "abc"}, "optimizer")


def test_config_errors_turns_validation_errors_into_input_errors():
    with pytest.raises(InputError, match=r"^bad value$") as info:
        with config_errors():
            raise ValueError("bad value")
    assert isinstance(info.value.__cause__, ValueError)
    wrapped = InstantiationException("Error in call to target 'x':\nValueError('y')")
    wrapped.__cause__ = ValueError("sim.max_dt must be > 0 s, got -1")
    with pytest.raises(InputError, match=r"^sim.max_dt must be > 0 s, got -1$"):
        with config_errors():
            raise wrapped
    with pytest.raises(KeyError), config_errors():  # not a validation error: unchanged
        raise KeyError("k")


def test_report_user_errors_prints_one_line_and_exits_2(capsys):
    @report_user_errors
    def entry(exc):
        raise exc

    for exc, line in (
        (
            InputError("seed must be an integer >= 0, got 'abc'"),
            "error: seed must be an integer >= 0, got 'abc'",
        ),
        (MaterialError("class_id must be\nan integer"), "error: class_id must be an integer"),
        (
            FileNotFoundError("dataset directory x does not exist"),
            "error: dataset directory x does not exist",
        ),
    ):
        with pytest.raises(SystemExit) as info:
            entry(exc)
        assert info.value.code == 2
        assert capsys.readouterr().err == line + "\n"
    wrapped = InstantiationException("Error in call to target 'x'")
    wrapped.__cause__ = FileNotFoundError("no such checkpoint")
    with pytest.raises(SystemExit):
        entry(wrapped)
    assert capsys.readouterr().err == "error: no such checkpoint\n"
    for programming_error in (TypeError("bug"), ValueError("a bug, not input")):
        with pytest.raises(type(programming_error)):
            entry(programming_error)
    assert capsys.readouterr().err == ""
