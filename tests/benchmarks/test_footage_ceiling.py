"""The footage ceiling: held-out probes find a carried value and read noise as its null."""

import numpy as np
import pytest

from benchmarks.footage_ceiling import main, probe_r, state_features


def _footage(carried: bool, seed: int = 0):
    """30 fabrics x 3 winds x 3 clips; the features carry the value or only the wind."""
    rng = np.random.default_rng(seed)
    values, groups, clips, rows = {}, {}, [], []
    for fabric in range(30):
        value = rng.normal()
        for wind in range(3):
            video = f"v{fabric:02d}{wind}"
            values[video], groups[video] = value, f"f{fabric:02d}"
            for _ in range(3):
                noise = rng.normal(size=12)
                signal = np.zeros(12)
                signal[0] = value if carried else 0.0
                signal[1] = wind  # a nuisance every video has
                rows.append(signal + 0.5 * noise)
                clips.append(video)
    return np.array(rows), np.array(clips), values, groups


def test_a_carried_value_is_found_beyond_its_null():
    x, clips, values, groups = _footage(carried=True)
    found = probe_r(x, clips, values, groups, n_boot=200, n_null=20)
    assert found["r"] > 0.8 and found["r_ci"][0] > 0.5
    assert found["p"] <= 1 / 21 + 1e-9 and found["null_p95"] < 0.5
    assert found["videos"] == 90 and set(found["predicted"]) == set(values)


def test_noise_reads_as_its_null_not_as_a_negative_ceiling():
    ps = []
    for seed in range(3):
        x, clips, values, groups = _footage(carried=False, seed=seed)
        found = probe_r(x, clips, values, groups, n_boot=50, n_null=20, seed=seed)
        assert found["r"] < found["null_p95"] + 0.2
        ps.append(found["p"])
    assert max(ps) > 0.1  # not all below the null: nothing is found in noise


def test_a_folder_without_a_diagnosis_is_refused_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--report", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --report")


def test_state_features_log_numbers_one_hot_words_and_a_slope_per_word():
    rows = [
        {"video": "a", "speed": "0.1", "strain": "-0.5", "wind": "W1"},
        {"video": "b", "speed": "0.4", "strain": "0.5", "wind": "W2"},
        {"video": "c", "speed": "1.6", "strain": "1.5", "wind": "W1"},
    ]
    x = state_features(rows, ["speed", "strain", "wind"])
    assert list(x) == ["a", "b", "c"]
    # log speed, strain as is (not all positive), W1, W2, speed*W1, speed*W2, strain*W1, ...
    assert x["b"] == pytest.approx([np.log(0.4), 0.5, 0, 1, 0, np.log(0.4), 0, 0.5])
    assert x["c"][:5] == pytest.approx([np.log(1.6), 1.5, 1, 0, np.log(1.6)])


def test_a_value_the_motion_carries_per_wind_is_read_from_the_state():
    rng = np.random.default_rng(1)
    rows, values, groups = [], {}, {}
    for fabric in range(30):
        density = rng.uniform(0.1, 0.3)
        for wind, gain in (("W1", 1.0), ("W2", -1.0)):  # the sign of the effect flips with wind
            video = f"v{fabric:02d}{wind}"
            speed = np.exp(gain * np.log(density) + 0.1 * rng.normal())
            rows.append({"video": video, "speed": f"{speed:.6g}", "wind": wind})
            values[video], groups[video] = np.log(density), f"f{fabric:02d}"
    x = state_features(rows, ["speed", "wind"])
    clips = np.array(list(x))
    found = probe_r(np.stack([x[v] for v in clips]), clips, values, groups, n_boot=50, n_null=20)
    assert found["r"] > 0.8 and found["p"] <= 1 / 21 + 1e-9
    without_wind = state_features(rows, ["speed"])
    lost = probe_r(np.stack([without_wind[v] for v in clips]), clips, values, groups, n_null=0)
    assert lost["r"] < 0.5  # one slope for both winds cannot read it


def test_a_state_column_that_is_not_finite_is_refused():
    from common.errors import InputError

    with pytest.raises(InputError, match="--state-columns: speed"):
        state_features([{"video": "a", "speed": "nan"}], ["speed"])
    rows = [{"video": "a", "speed": "0.1"}, {"video": "b", "speed": ""}]  # a blank: refused
    with pytest.raises(InputError, match="speed mixes numbers"):
        state_features(rows, ["speed"])


def test_a_reader_fitted_on_simulations_transfers_what_both_domains_share():
    from benchmarks.footage_ceiling import sim_readout

    rng = np.random.default_rng(2)

    def clips(n, shift, carried=True):
        value = rng.uniform(-1, 1, n)
        x = rng.normal(size=(n, 8))
        x[:, 0] += 2 * value if carried else 0.0
        return x + shift, value

    x_sim, y_sim = clips(160, 0.0)
    x_real, y_real = clips(90, 0.7)  # the same relation, the features offset by the domain
    videos = np.array([f"v{i:02d}" for i in range(90)])
    values = dict(zip(videos, y_real, strict=True))
    groups = {v: f"f{i // 3}" for i, v in enumerate(videos)}
    found = sim_readout(x_sim, y_sim, x_real, videos, values, groups, n_boot=100)
    assert found["r"] > 0.7 and found["r_ci"][0] > 0.4 and found["videos"] == 90
    x_none, _ = clips(90, 0.7, carried=False)  # R's features do not carry it
    lost = sim_readout(x_sim, y_sim, x_none, videos, values, groups, n_boot=100)
    assert abs(lost["r"]) < 0.3
    same = sim_readout(x_sim, np.full(160, 0.3), x_real, videos, values, groups, n_boot=10)
    assert same["varied"] is False and np.isnan(same["r"])  # one simulated value: no fit
