"""sweep: system identification of the MMG model on the FRT-DS-ESSO free-running recordings.

Data layer: :mod:`sweep.recordings` (validated in-memory recordings, CSV/Parquet I/O),
:mod:`sweep.datasets` (the paper's train/test split, data directory), :mod:`sweep.download`
(fetching the recordings at a pinned commit).
"""
