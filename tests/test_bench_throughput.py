"""``python -m jdpim.bench throughput``: one row per method and size, with the noise drawn inside the steps and the
mirror rule as options, the kernel density's time counted in the path-steps per second."""

import datetime
import json

import pytest

import jdpim
from jdpim.bench.__main__ import main


def test_throughput_rows_with_nodes_and_the_mirror_rule(tmp_path):
    argv = ["throughput", "--sizes", "16", "--t-end", "10", "--repeats", "1", "--out", str(tmp_path)]
    assert main([*argv, "--forcing", "nodes", "--impacts", "mirror"]) == 0
    info = json.loads((tmp_path / "throughput.json").read_text())
    (row,) = info["rows"]  # DPIM needs the spectral representation: Monte Carlo alone
    assert (row["method"], row["forcing"], row["impacts"], row["n_paths"]) == ("monte_carlo", "nodes", "mirror", 16)
    assert row["n_nonfinite"] == 0
    assert 0 < row["kde_s"] < row["median_s"]
    assert row["path_steps_per_s"] == pytest.approx(16 * 1000 / row["median_s"], rel=0.01)  # median_s is rounded
    assert "| nodes | mirror | monte_carlo | 16 |" in (tmp_path / "throughput.md").read_text()
    rec = info["record"]  # every bench's record: date, machine, versions, load, protocol
    assert datetime.datetime.fromisoformat(rec["date"]).tzinfo is not None
    assert rec["machine"]["cores"] >= 1 and rec["machine"]["cpu"] and rec["machine"]["devices"]
    assert rec["versions"]["jdpim"] == jdpim.__version__ and rec["versions"]["jax"] and rec["versions"]["python"]
    assert len(rec["load_average"]) == 3 and "median" in rec["protocol"]
    assert (tmp_path / "throughput.md").read_text().startswith(f"Measured {rec['date']}; CPU: ")


def test_dpim_alone_with_nodes_fails_in_one_line(tmp_path, capsys):
    argv = ["throughput", "--methods", "dpim", "--forcing", "nodes", "--out", str(tmp_path)]
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert "--methods dpim needs the spectral forcing" in capsys.readouterr().err
    assert not (tmp_path / "throughput.json").exists()
