"""The room console (`vts console`): a local web application for the people at the scanner.

An application layer like the CLI: it opens the rig's devices through the room (vts_hw.room),
calls the procedures, the store and the reports, and holds no procedure logic of its own. It
never imports the CLI nor the simulator. ``serve.serve`` runs it; the Room page is built from
``hub`` (the latest frame of each camera, one stream per camera at most), ``markers`` (detection
on those frames), ``names`` (what each marker is), ``room`` (LED read back, clock offsets, daily
QA) and ``app`` (the pages and events). docs/decisions/0060-room-console.md, 0066.
"""
