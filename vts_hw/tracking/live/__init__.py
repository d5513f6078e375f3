"""Live patient motion during a scan: a tap on the recording's frames, a worker that tracks the
markers, and an estimator of the body's pose with breathing separated, with alerts.

The core only (no driver, procedure or simulator): ``tap`` (bounded per-camera queues that drop
the oldest for the live path only), ``tracker`` (the worker; frame sets across cameras by
:mod:`vts_hw.tracking.frame_sets`, identities by :mod:`vts_hw.tracking.identities`: the
processing's own rules), ``reference`` (the reference period: the patient's markers by the one
identity of :mod:`vts_hw.vision.marker_roles`), ``estimator`` (the one patient model of
:mod:`vts_hw.motion.patient_model` fitted one instant at a time, and the snapshot a view prints),
``pose_log`` (the model and every pose kept in the scan's folder), ``breathing`` (trace and rate),
``alerts`` (the alert rule). See docs/decisions/0036-live-motion.md and 0092.
"""
