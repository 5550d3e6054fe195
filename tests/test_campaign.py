"""Monte Carlo campaigns: reproducible trials, resume, process executor, validation."""

import numpy as np
import pytest

from uuv_ocp import cli
from uuv_ocp.studies.campaign import CampaignConfig, run_campaign


def small(**changes):
    settings = {"reference": "s2", "trials": 2, "duration": 0.5, "horizon": 8, "seed": 3}
    settings.update(changes)
    return CampaignConfig(**settings)


def test_campaign_resumes_and_processes_agree(tmp_path):
    local = run_campaign(small(), tmp_path / "a", progress=False)
    files = sorted(local.directory.glob("trial_*.npz"))
    assert len(files) == 2
    stamps = [f.stat().st_mtime_ns for f in files]
    again = run_campaign(small(), tmp_path / "a", progress=False)
    assert [f.stat().st_mtime_ns for f in files] == stamps  # resumed from disk
    assert again.summary == local.summary
    parallel = run_campaign(small(), tmp_path / "b", executor="process", workers=2, progress=False)
    for left, right in zip(local.trials, parallel.trials, strict=True):
        np.testing.assert_allclose(left["max_abs_ex"], right["max_abs_ex"], rtol=0, atol=0)
    assert local.summary["trials"] == 2 and local.summary["failures"] == 0
    assert local.summary["mean_var_ex"] == pytest.approx(np.mean([t["var_ex"] for t in local.trials]))


def test_trials_differ_and_settings_change_the_folder(tmp_path):
    result = run_campaign(small(), tmp_path, progress=False)
    assert result.trials[0]["max_abs_ey"] != result.trials[1]["max_abs_ey"]
    assert small().name != small(duration=0.6).name


@pytest.mark.parametrize(
    ("changes", "name"),
    [({"trials": 0}, "trials"), ({"reference": "s0"}, "s0"), ({"duration": -1.0}, "duration")],
)
def test_bad_configuration_raises(changes, name):
    with pytest.raises(ValueError, match=name):
        small(**changes)


def test_cli_campaign(tmp_path, capsys):
    code = cli.main(["campaign", "--trials", "1", "--duration", "0.3", "--out", str(tmp_path)])
    assert code == 0
    assert "1 trials" in capsys.readouterr().out
    assert cli.main(["campaign", "--solver", "newton", "--out", str(tmp_path)]) == 2
