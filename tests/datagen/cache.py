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
