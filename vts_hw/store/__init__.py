"""The results store: QA runs, measurements, tolerance windows and artifacts.

    from vts_hw.store import ResultsStore
    with ResultsStore() as store:                     # default: a per-user SQLite file
        with store.begin_run("drift", rig="vts") as run:
            run.measure("cam1", "drift_x_px", 0.4)
            run.artifact("frames/cam1.jpg")
        # normal exit: finished in one transaction; an exception: aborted

``ResultsStore(url)`` takes an SQLite file or URL, or ``postgresql://user@host/db`` (psycopg 3;
the password from the environment variable named by ``password_env``, never in the URL);
target.py picks the store a command uses (--store, $VTS_STORE, rig.yaml's store:), copy.py
copies one store into another (`vts store migrate`).

See store.py for the API, schema.py for the tables, docs/decisions/0007-results-store.md,
0038-postgresql-store.md and 0039-store-migrate.md for the reasons.
"""

from vts_hw.store.errors import StoreError
from vts_hw.store.handle import RunHandle
from vts_hw.store.paths import StoreTarget, default_path, default_url
from vts_hw.store.records import MEASUREMENT_STATUSES, RUN_STATUSES, Artifact, Measurement, Run
from vts_hw.store.schema import SCHEMA_VERSION
from vts_hw.store.store import ResultsStore

__all__ = [
    "ResultsStore",
    "StoreTarget",
    "RunHandle",
    "Run",
    "Measurement",
    "Artifact",
    "StoreError",
    "default_url",
    "default_path",
    "RUN_STATUSES",
    "MEASUREMENT_STATUSES",
    "SCHEMA_VERSION",
]
