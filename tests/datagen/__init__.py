"""Test-data generator: a richer, independent truth model writing the shared CSV format.

Run ``python -m tests.datagen --help`` to make data sets by hand; the identification tests
use it through session fixtures.
"""
