"""Writing the shared measured-data format, and the current channel of a bench or controller.

The generator writes its files itself (shared/measured-data-format.md), without the suite's
writer, so a column the suite does not know yet (``coil_voltage_mean``) can be written and a
writer bug of the suite cannot shape the data it is tested on.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

__all__ = ['write_table', 'bench_current']


def _format_value(value: object) -> str:
    return f'{value:.10g}' if isinstance(value, float) else str(value)


def write_table(path: str | Path, metadata: Mapping[str, object],
                columns: Mapping[str, np.ndarray]) -> Path:
    """Write ``# key: value`` lines, a header and the columns (10 significant digits).

    Parameters
    ----------
    path : str or pathlib.Path
        Destination (parent directories are created).
    metadata : mapping
        Metadata in the order to write; floats with 10 significant digits.
    columns : mapping of str to numpy.ndarray, each shape (n,)
        Columns in the order to write; ``nan`` is written as an empty field.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    names = list(columns)
    data = [np.asarray(columns[c], dtype=float) for c in names]
    if len({d.shape for d in data}) != 1:
        raise ValueError(f'columns {names} differ in length')
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    table = np.column_stack(data)
    with open(out, 'w', encoding='utf-8', newline='\n') as fh:
        for key, value in metadata.items():
            fh.write(f'# {key}: {_format_value(value)}\n')
        fh.write(','.join(names) + '\n')
        if np.all(np.isfinite(table)):
            np.savetxt(fh, table, fmt='%.10g', delimiter=',')
        else:
            for row in table:
                fh.write(','.join('%.10g' % v if math.isfinite(v) else '' for v in row) + '\n')
    return out


def bench_current(current_a: np.ndarray, rng: np.random.Generator, noise_a: float,
                  lsb_a: float = 0.0, adc_bits: int = 8) -> np.ndarray:
    """The current as a channel reports it: Gaussian noise, then optional quantisation.

    Parameters
    ----------
    current_a : numpy.ndarray, shape (n,)
        True current [A].
    rng : numpy.random.Generator
        Draws the noise (nothing is drawn when ``noise_a`` is 0).
    noise_a : float
        Standard deviation of the noise [A].
    lsb_a : float
        Quantisation step [A]; 0 keeps the values unquantised.
    adc_bits : int
        Resolution of a unipolar converter: codes 0 .. 2^adc_bits - 1 (a negative current
        reads 0, a current beyond the range its largest code).

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    noisy = current_a + (rng.normal(0.0, noise_a, current_a.size) if noise_a > 0.0 else 0.0)
    if lsb_a <= 0.0:
        return noisy
    # (+ 0.0: a code of -0.0 reads 0)
    codes = np.clip(np.round(noisy / lsb_a), 0, 2 ** adc_bits - 1) + 0.0
    return codes * lsb_a
