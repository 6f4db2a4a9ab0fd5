"""The atlas table on disk: Parquet (pyarrow), one row per (position, rotation), units in the
column names, written under a temporary name and renamed (:func:`oma.io.atomic_write`).

A pandas or Dask user opens it directly (``pandas.read_parquet(path)``,
``dask.dataframe.read_parquet(path)``). The atlas's description (region, setup, method, units)
is stored as JSON in the file's key-value metadata under ``robomill-atlas``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

import numpy as np

from oma.io import atomic_write

__all__ = ["write_table", "read_table", "METADATA_KEY"]

METADATA_KEY = b"robomill-atlas"


def write_table(path, columns: Mapping[str, np.ndarray], *, metadata: Mapping | None = None):
    """Write the columns (equal lengths; numeric, bool or str) as one Parquet file, atomically.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({name: pa.array(np.asarray(values)) for name, values in columns.items()})
    if metadata is not None:
        table = table.replace_schema_metadata({METADATA_KEY: json.dumps(metadata).encode()})
    with atomic_write(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    return path


def read_table(path) -> tuple[dict[str, np.ndarray], dict]:
    """The columns (NumPy arrays) and the metadata of a table :func:`write_table` wrote."""
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    meta = table.schema.metadata or {}
    info = json.loads(meta[METADATA_KEY]) if METADATA_KEY in meta else {}
    return {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}, info
