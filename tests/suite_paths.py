"""Paths of the repository for tests (a module of its own: `conftest` names are ambiguous)."""
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
