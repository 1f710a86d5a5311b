"""Real Crazyflie flights (CrazyPAD): convert, identify from normal flights, name what is wrong (issue 13).

    .venv/bin/python bench/bench_crazypad.py [--data ../shared/data/crazypad/motor_data] [--markdown]

``--data ../shared/data/crazypad/controller_data`` runs the same on CrazyPAD's other flights, which log
the PID controller instead of the motors (the converter rebuilds the motor commands by the firmware's
mixer): 29 flights that no threshold or model choice here was tuned on.

For every flight in the data's folders (normal_flight, cut_propeller_*, tape_on_propeller_*,
add_weight_*): the baseline is the normal flights of the same session (the file name's E8/E9 prefix:
the vehicle as it was built that day), leaving out the flight under test; `identify` fits k_f, the
effects of ``--effects`` (default motor_lag: the Crazyflie's rotors answer in about 30 ms) and the
rotor balance to them, `discrepancy` runs on the flight against the identified airframe. The table gives
the truth (the folder), what was named, e_1..e_4 with standard deviations and the weakest rotor's z
("or M_k": rotors the rotor balance cannot tell from the weakest, ``indistinct_rotors``).

Timing, per flight, in CPU time of this process (the machine is shared): `convert` of the binary log,
the rotor balance alone (flight_balance + diagnose), and the whole `discrepancy` (translational
workflow and rotor balance, no plots) -- the goal is convert + discrepancy under 10 s.
"""

from __future__ import annotations

import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from multirotor_ros.discrepancy.workflow import find_discrepancy  # noqa: E402
from multirotor_ros.ident.identify import identify  # noqa: E402
from multirotor_ros.ident.rotor_balance import RotorBaseline, diagnose, flight_balance  # noqa: E402
from multirotor_ros.io.convert import convert  # noqa: E402
from multirotor_ros.model.airframe import Airframe, airframe_from_dict, load_airframe  # noqa: E402
from multirotor_ros.model.effects import parse_effect_list  # noqa: E402

LIMIT_S = 10.0
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "crazypad" / "motor_data"


def _cpu() -> float:
    return time.process_time()


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--data", type=Path, default=DEFAULT_DATA, help="CrazyPAD motor_data or controller_data folder"
    )
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown (README)")
    parser.add_argument(
        "--effects",
        default="motor_lag",
        help="effects identified on the normal flights (comma-separated, or none)",
    )
    args = parser.parse_args()
    airframe = load_airframe("crazyflie_2_1")
    effects = parse_effect_list(args.effects)
    paths = sorted(args.data.glob("*/E*"))
    if not paths:
        parser.error(f"no flights under {args.data}")

    logs, convert_s = {}, []
    for path in paths:
        started = _cpu()
        logs[path] = convert(path, airframe).log
        convert_s.append(_cpu() - started)

    identified: dict[tuple[Path, ...], Airframe] = {}
    rows, balance_s, discrepancy_s = [], [], []
    for path in paths:
        session = path.name[:2]
        baseline_paths = tuple(
            p for p in paths if p.parent.name == "normal_flight" and p.name[:2] == session and p != path
        )
        if baseline_paths not in identified:
            result = identify(airframe, [logs[p] for p in baseline_paths], effects)
            identified[baseline_paths] = airframe_from_dict(result.airframe_document(), origin="identified")
        vehicle = identified[baseline_paths]
        baseline = RotorBaseline.of_airframe(vehicle)
        assert baseline is not None
        started = _cpu()
        diagnosis = diagnose(vehicle, baseline, flight_balance(logs[path], vehicle))
        balance_s.append(_cpu() - started)
        started = _cpu()
        report = find_discrepancy(vehicle, logs[path])
        discrepancy_s.append(_cpu() - started)
        weakest = int(np.argmin(diagnosis.effectiveness))
        rows.append(
            [
                f"{path.parent.name}/{path.name}",
                f"{len(baseline_paths)} {session}",
                report.verdict(),
                *(
                    f"{e:.3f} ± {s:.3f}"
                    for e, s in zip(diagnosis.effectiveness, diagnosis.effectiveness_std, strict=True)
                ),
                f"M{weakest + 1} {diagnosis.z_scores[weakest]:+.1f}"
                + "".join(f" or M{k}" for k in diagnosis.indistinct_rotors),
            ]
        )
    headers = ["flight", "baseline", "named", "e_1", "e_2", "e_3", "e_4", "weakest, z"]
    if args.markdown:
        print("| " + " | ".join(headers) + " |")
        print("|" + "---|" * len(headers))
        for row in rows:
            print("| " + " | ".join(row) + " |")
    else:
        for row in rows:
            print("  ".join(row))
    worst = max(c + d for c, d in zip(convert_s, discrepancy_s, strict=True))
    print(
        f"\nper flight, CPU s (median / max over {len(paths)}): convert {np.median(convert_s):.3f} / "
        f"{max(convert_s):.3f}; rotor balance alone {np.median(balance_s):.3f} / {max(balance_s):.3f}; "
        f"discrepancy {np.median(discrepancy_s):.2f} / {max(discrepancy_s):.2f}; "
        f"convert + discrepancy worst {worst:.2f} (limit {LIMIT_S:g})"
    )
    return 0 if worst < LIMIT_S else 1


if __name__ == "__main__":
    raise SystemExit(main())
