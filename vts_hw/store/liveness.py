"""Who wrote a "running" row, and whether that process is still alive: the one model of a
process's identity and life, :mod:`vts_hw.lifeline` (host name, pid and a process-start token;
a pid reused after the writer died, or a reboot since, is not mistaken for the writer), which
the recordings' manifests use too.

Only runs written on this host can be judged; runs of other hosts (a shared PostgreSQL
server) are left as they are.
"""

from __future__ import annotations

from vts_hw.lifeline import host_name, is_alive, process_start

__all__ = ["host_name", "is_alive", "process_start"]
