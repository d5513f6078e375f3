"""Recording folders: their format, writing, reading, capture, the index and reindex (tracking them is vts_hw.tracking)."""
