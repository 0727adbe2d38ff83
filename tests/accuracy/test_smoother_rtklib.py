"""Forward-backward smoothing on the rtklibexplorer car drive, scored against the withheld RTK fixes (the drive's
only reference; inside the windows the withheld fixes are independent of the solution)."""
from __future__ import annotations

import numpy as np

from zennav.metrics import evaluate
from zennav.replay import run_replay


def test_smoothing_bounds_the_withheld_fix_windows_from_both_ends(rtklib_dataset):
    res = run_replay(rtklib_dataset, outage_every=(90.0, 30.0, 60.0), smoothing=True)
    assert res.smoothed is not None
    fwd, smo = evaluate(rtklib_dataset, res), evaluate(rtklib_dataset, res.smoothed)
    peaks_fwd = np.array([o["max_horizontal_m"] for o in fwd["outages"]])
    peaks_smo = np.array([o["max_horizontal_m"] for o in smo["outages"]])
    print("outage peaks forward", peaks_fwd.round(2), "smoothed", peaks_smo.round(2),
          "horizontal RMS", round(fwd["horizontal_rms_m"], 3), round(smo["horizontal_rms_m"], 3))
    assert len(peaks_smo) == 5 and np.all(peaks_smo < peaks_fwd)
    assert smo["outage_max_horizontal_rms_m"] < 0.1 * fwd["outage_max_horizontal_rms_m"]
    assert smo["outage_max_horizontal_max_m"] < 10.0
    assert smo["horizontal_rms_m"] < 0.2 * fwd["horizontal_rms_m"]
    assert res.smoothed.status["smoother"]["segments"] == 1
