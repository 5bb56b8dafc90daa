"""Generated data sets for the tests, written once per test session into a temporary folder."""
from __future__ import annotations

from pathlib import Path

from .generate import generate_case

_CACHE: dict[tuple[str, int, bool], dict[str, object]] = {}


def dataset(base_dir: Path, case: str, seed: int = 1, long: bool | None = None
            ) -> dict[str, object]:
    """The truth.json content of a case (generated on first use into ``base_dir``)."""
    key = (case, seed, bool(long))
    if key not in _CACHE:
        _CACHE[key] = generate_case(base_dir / f'seed{seed}{"-long" if long else ""}', case,
                                    seed=seed, long=long)
    return _CACHE[key]


_OPERATION_CACHE: dict[tuple, dict[str, object]] = {}


def operation_dataset(base_dir: Path, *, seed: int = 1, effect: str = 'none',
                      noise_a: float = 0.0, duration_s: float = 3.0, spread: float = 0.0
                      ) -> dict[str, object]:
    """The truth JSON of an operational record (written on first use into ``base_dir``)."""
    from .operation import write_operation_record
    key = (seed, effect, float(noise_a), float(duration_s), float(spread))
    if key not in _OPERATION_CACHE:
        name = (f'operation-{effect}-seed{seed}-{1e3 * noise_a:g}mA-{duration_s:g}s'
                f'-spread{spread:g}')
        _OPERATION_CACHE[key] = write_operation_record(
            base_dir / 'operation', name, seed=seed, effect=effect, noise_a=noise_a,
            duration_s=duration_s, spread=spread)
    return _OPERATION_CACHE[key]
