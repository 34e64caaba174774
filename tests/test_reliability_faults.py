"""The fault suite: a board pulled, babbling or silent at every kind of moment (issue 9).

Each trial must end with every pending instruction answered once, nothing
replayed and the pose learnt again; the times are written to
`build/reliability/faults.json` (targets, checked in `make soak`: fault within
1 s idle and 0.3 s mid-move, back within 1 s of the re-plug).
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest

from al5d.arm.config import ArmConfig
from al5d.ssc32u.emulator import Fault
from al5d_rig.faultrig import MOMENTS, Trial, run_trial

OUT = Path(__file__).resolve().parents[1] / "build" / "reliability"
TRIALS: list[Trial] = []


@pytest.mark.parametrize("fault", list(Fault))
@pytest.mark.parametrize("moment", MOMENTS)
def test_a_fault_at_each_moment(
    config: ArmConfig, tmp_path: Path, moment: str, fault: Fault
) -> None:
    trial = run_trial(config, tmp_path, moment, fault, random.Random(f"{moment}{fault}"))
    TRIALS.append(trial)
    assert trial.ok, trial
    assert trial.to_fault_s < 5  # generous: only that the fault was seen at all
    if moment != "shutdown-park":
        assert trial.to_back_s < 5


def test_write_the_figures() -> None:
    if not TRIALS:
        pytest.fail("no trial ran before this one")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "faults.json").write_text(json.dumps([t.__dict__ for t in TRIALS], indent=1))
