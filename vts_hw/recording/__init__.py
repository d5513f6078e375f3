"""Recording folders: their format, writing, reading, capture, reindex, processing, tracks."""
