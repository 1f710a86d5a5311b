"""The model-discrepancy workflow: where model and log disagree, which effect is missing, the gap after.

    from multirotor_ros.discrepancy import find_discrepancy
    report = find_discrepancy("x8_octorotor", "flight.csv", baseline_effects=[], max_effects=1)
    report.missing_effect, report.parameters, report.mse_before, report.mse_after
    report.to_json()            # report.json of shared/spec/interfaces.md
    report.write("out_dir")     # report.json, PNG plots, self-contained report.html

See :mod:`.workflow` for the method, :mod:`.regimes` for where the error is, :mod:`.report` for output,
:mod:`.settings` for the thresholds.
"""

from multirotor_ros.discrepancy.settings import DiscrepancySettings
from multirotor_ros.discrepancy.workflow import Candidate, DiscrepancyReport, find_discrepancy

__all__ = ["Candidate", "DiscrepancyReport", "DiscrepancySettings", "find_discrepancy"]
