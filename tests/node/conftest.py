"""Node tests need rclpy; the fixtures they use (``start_node``, ``ros``) are tests/conftest.py's.

The helpers (processes, waits, diagnostics, duty commands) are in tests/node_harness.py.
"""
from __future__ import annotations

import pytest

pytest.importorskip('rclpy')
