"""Attitude core: seed 000's adaptive PI complementary filter (numpy/scipy only, no transport)."""
