"""Pushing results to the clinic's QATrack+ (its REST API), through the store's outbox.

- ``client.QATrackClient``: the part of QATrack+'s API the push uses (token, assignments,
  test list instances), with three kinds of failure (Unreachable, Refused, AuthRefused);
- ``payload``: what a run becomes there (values under their macros, times, comment with the
  key ``vts-run-<uid>``, the drift plot and report as attachments);
- ``push``: the outbox logic (never twice, never lost) and the runs a push takes.

This layer sits above the reports (it builds them): config → ... → store → report → qatrack.
"""

from vts_hw.qatrack.client import AuthRefused, QATrackClient, QATrackError, Refused, Unreachable
from vts_hw.qatrack.payload import NotMapped, build_payload, run_key
from vts_hw.qatrack.push import TARGET, Outcome, dry_run, exit_code, push_runs, select_runs

__all__ = [
    "QATrackClient",
    "QATrackError",
    "Unreachable",
    "Refused",
    "AuthRefused",
    "NotMapped",
    "build_payload",
    "run_key",
    "TARGET",
    "Outcome",
    "push_runs",
    "select_runs",
    "dry_run",
    "exit_code",
]
