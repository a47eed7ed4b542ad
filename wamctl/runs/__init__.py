"""Run directories and data files: the run directory (:mod:`.store`: manifest, status, chunked tables, events)
and the measured-run format (:mod:`.measured`: meta.yaml + data, import and export).

May import: model (joint count, transmissions), io, errors. Nothing above.
"""
