"""Time series of fixed-shape rows kept in bounded memory: full blocks go to files on disk.

A run of hours samples every robot 20 times a second (about 0.6 kB a row with 9 robots): kept
as Python lists that grew by 2.7 MB a minute. SampleLog holds one block of rows per field in
numpy arrays and appends each full block to a raw file of that field, so its memory does not
grow with the run; `arrays()` reads everything back when the run is measured.
"""

from pathlib import Path
import shutil
import tempfile
from typing import Any
import weakref

import numpy as np


BLOCK_ROWS = 512   # rows held in memory per field before they go to disk


class SampleLog:
    """Rows of named fields, each field an array of one shape and dtype throughout.

    fields: {name: (shape tuple, dtype)}; directory: where the field files go (created; by
    default a private temporary directory, removed by close() or when the log is collected).
    """

    def __init__(self, fields: dict[str, tuple[tuple[int, ...], Any]],
                 directory: str | Path | None = None, block_rows: int = BLOCK_ROWS) -> None:
        self._remove: weakref.finalize | None = None
        if directory is None:
            directory = tempfile.mkdtemp(prefix='curve_formation-samples-')
            self._remove = weakref.finalize(self, shutil.rmtree, directory, ignore_errors=True)
        else:
            Path(directory).mkdir(parents=True, exist_ok=True)
        self.directory = Path(directory)
        self.fields = {name: (tuple(shape), np.dtype(dtype))
                       for name, (shape, dtype) in fields.items()}
        self.block_rows = block_rows
        self._block = {name: np.empty((block_rows, *shape), dtype)
                       for name, (shape, dtype) in self.fields.items()}
        self._held = 0       # rows in the block
        self._written = 0    # rows on disk
        self._last: dict[str, Any] | None = None
        for name in self.fields:
            self._path(name).write_bytes(b'')

    def _path(self, name: str) -> Path:
        return self.directory / f'{name}.bin'

    def __len__(self) -> int:
        return self._written + self._held

    def append(self, **row: Any) -> None:
        """Add one row: a value for every field, of its shape."""
        if row.keys() != self.fields.keys():
            raise KeyError(f'a row has fields {sorted(row)}; expected {sorted(self.fields)}')
        for name, value in row.items():
            self._block[name][self._held] = value
        self._last = row
        self._held += 1
        if self._held == self.block_rows:
            self.flush()

    def last(self, name: str) -> Any:
        """The newest row's value of a field (None before the first row)."""
        return None if self._last is None else self._last[name]

    def flush(self) -> None:
        """Append the rows held in memory to the field files."""
        if not self._held:
            return
        for name, block in self._block.items():
            with open(self._path(name), 'ab') as f:
                f.write(block[:self._held].tobytes())
        self._written += self._held
        self._held = 0

    def arrays(self) -> dict[str, np.ndarray]:
        """{name: array (rows, *shape)} of every row so far (read from disk: a copy)."""
        out = {}
        for name, (shape, dtype) in self.fields.items():
            stored = np.fromfile(self._path(name), dtype=dtype).reshape(-1, *shape)
            out[name] = np.concatenate([stored, self._block[name][:self._held]])
        return out

    def close(self) -> None:
        """Remove the field files of a temporary directory (a given directory is kept)."""
        if self._remove is not None:
            self._remove()

    def __enter__(self) -> 'SampleLog':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
