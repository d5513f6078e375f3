"""Live patient motion during a scan: a tap on the recording's frames, a worker that tracks the
markers, and an estimator of the body's pose with breathing separated, with alerts.

The core only (no driver, procedure or simulator): ``tap`` (bounded per-camera queues that drop
the oldest for the live path only), ``tracker`` (the worker; frame sets across cameras by
:mod:`vts_hw.tracking.frame_sets`, identities by :mod:`vts_hw.tracking.identities`: the
processing's own rules), ``model`` (the reference and
the breathing-separated rigid fit), ``breathing`` (trace and rate), ``alerts`` (the alert
rule), ``estimator`` (all of it, and the snapshot a view prints). See
docs/decisions/0036-live-motion.md.
"""
