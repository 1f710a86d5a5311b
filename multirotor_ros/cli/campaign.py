"""``multirotor campaign {fault,sweep,logs} ... --out DIR``: batch work on a Dask cluster, resumable."""

from __future__ import annotations

import argparse
from pathlib import Path

from multirotor_ros.cli import CommandError

COMMAND = "campaign"
HELP = "run fault and fault-tolerance campaigns, the hidden-effect sweep, or identify/discrepancy over logs"

DESCRIPTION = """\
Run many cases on a Dask cluster: by default a local one with one worker process per core, or the
existing cluster whose scheduler is given with --scheduler tcp://HOST:PORT (its workers need this package
and, for logs, the same paths). Every case is a pure function of its description and seed: a rerun gives
the same table. A failed case is reported with its error and the others go on.

Results stream to DIR/results/*.parquet as cases finish; run the same command again after an
interruption and it resumes with the cases not done yet (--retry-failed also reruns the failed ones).
At the end: a summary on the terminal and DIR/summary.html (plots embedded; for logs, a link to every
log's report under DIR/reports/).
"""

EPILOG = """\
examples:
  multirotor campaign fault --airframe x8_octorotor --faults 104 --out runs/x8
  multirotor campaign recovery --airframe x8_octorotor --cases 50 --out runs/x8_recovery
  multirotor campaign sweep --only x8-rotor_drag --out runs/sweep
  multirotor campaign logs 'fleet/**/*.ulg' --airframe quad_x --analysis discrepancy --out runs/fleet
  multirotor campaign fault --airframe hexarotor_f550 --scheduler tcp://10.0.0.5:8786 --out runs/hex
"""


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments: one sub-command per kind of campaign, the cluster options on each."""
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    kinds = parser.add_subparsers(dest="kind", required=True, metavar="KIND")
    fault = kinds.add_parser("fault", help="simulated rotor faults, diagnosed and scored (issue 4)")
    fault.add_argument("--airframe", action="append", help="airframe (repeatable); default X8 and hexarotor")
    fault.add_argument("--faults", type=int, default=0, help="faults per airframe (default 13 per rotor)")
    fault.add_argument("--seed", type=int, default=2024)
    fault.add_argument("--duration", type=float, default=3.5, help="flight per case [s]")
    fault.add_argument("--velocity-noise", type=float, default=0.02, help="estimator velocity noise [m/s]")
    recovery = kinds.add_parser(
        "recovery", help="fault-tolerant flight: faults flown with reallocation off and on"
    )
    recovery.add_argument(
        "--airframe", action="append", help="airframe (repeatable); default X8 and hexarotor"
    )
    recovery.add_argument("--cases", type=int, default=50, help="cases per airframe")
    recovery.add_argument(
        "--seed", type=int, default=1500, help="seed of the first case (then seed + 1, ...)"
    )
    sweep = kinds.add_parser("sweep", help="the hidden-effect sweep of the discrepancy workflow (issue 5)")
    sweep.add_argument("--only", help="the cases whose name contains this (names: x8-rotor_drag-s1-high)")
    logs = kinds.add_parser("logs", help="identify or discrepancy on every log of a folder or glob")
    logs.add_argument("source", help="a folder (searched recursively) or a glob (quote it)")
    logs.add_argument("--airframe", required=True, help="airframe config name or YAML path")
    logs.add_argument("--analysis", choices=("discrepancy", "identify"), default="discrepancy")
    logs.add_argument(
        "--effects",
        help="identify: the effects to fit (required); discrepancy: the baseline (default: the airframe's)",
    )
    logs.add_argument("--max-effects", type=int, default=1, help="discrepancy: name up to this many effects")
    logs.add_argument("--no-plots", action="store_true", help="reports without PNG plots")
    for sub in (fault, recovery, sweep, logs):
        sub.add_argument(
            "--out", required=True, type=Path, help="results directory (created; reused to resume)"
        )
        sub.add_argument("--scheduler", help="address of an existing Dask scheduler, tcp://HOST:PORT")
        sub.add_argument(
            "--workers", type=int, help="local cluster: worker processes (default: one per core)"
        )
        sub.add_argument("--retry-failed", action="store_true", help="run the failed cases of DIR again")
        sub.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Build the campaign, run what is not done, print the summary, write summary.html.

    Exit status 0 when every case ran, 1 when some failed.
    """
    from multirotor_ros.campaigns import fault, logs, recovery, sweep
    from multirotor_ros.campaigns.engine import ProgressBar, dask_client, run_campaign
    from multirotor_ros.campaigns.report import summary_lines, write_html
    from multirotor_ros.campaigns.store import CampaignMismatch
    from multirotor_ros.model.airframe import AirframeError
    from multirotor_ros.model.effects import parse_effect_list

    if args.workers is not None and (args.workers < 1 or args.scheduler):
        raise CommandError(
            "--workers must be >= 1 and applies to the local cluster only (not with --scheduler)"
        )
    try:
        if args.kind == "fault":
            campaign = fault.campaign(
                args.airframe or ["x8_octorotor", "hexarotor_f550"],
                args.faults,
                args.seed,
                args.duration,
                args.velocity_noise,
            )
        elif args.kind == "recovery":
            campaign = recovery.campaign(
                args.airframe or ["x8_octorotor", "hexarotor_f550"], args.cases, args.seed
            )
        elif args.kind == "sweep":
            campaign = sweep.campaign(args.only)
        else:
            effects = None if args.effects is None else parse_effect_list(args.effects)
            campaign = logs.campaign(
                args.source,
                args.airframe,
                args.analysis,
                args.out,
                effects,
                args.max_effects,
                not args.no_plots,
            )
    except (AirframeError, ValueError, OSError) as error:
        raise CommandError(str(error)) from None
    progress = None if args.quiet else ProgressBar(f"campaign {args.kind}", len(campaign.cases))
    try:
        with dask_client(args.scheduler, args.workers) as client:
            result = run_campaign(campaign, args.out, client, progress, retry_failed=args.retry_failed)
    except CampaignMismatch as error:
        raise CommandError(str(error)) from None
    except OSError as error:
        raise CommandError(f"cluster: {error}") from None
    print("\n".join(summary_lines(campaign, result.rows)))
    page = write_html(campaign, result.rows, args.out / "summary.html")
    print(f"wrote {page} ({result.computed} case(s) run now, {result.resumed} from earlier runs)")
    return 1 if result.failed else 0
